"""The experiment's decoders: which checkpoint each uses, training the defaults once, the component.

A checkpoint named in ``[decoder]`` is used as given. Otherwise the default decoder is the one
trained with the ``[train]`` settings at the experiment's resolution on the camera's images at
``[camera] blur``, named by a hash of what made it (the settings, and the blur when it is not the
default): the package ships the checkpoints of the default settings (``SHIPPED``, which `rhi train`
reproduces byte for byte, docs/decoders.md), and any other is trained once, the decoders side by side
(:mod:`rhi.master.runtime.pool`), and cached under ``$RHI_CACHE`` (default ``~/.cache/rhi``),
so a changed setting trains a new one and an unchanged one is reused.
Either way a loaded checkpoint is checked against the camera at the configured blur.
"""
from __future__ import annotations

import functools
import hashlib
import json
import logging
import os
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rhi.components.body import camera, kinematics
from rhi.master import models
from rhi.master.config import file_problem
from rhi.master.cosim import ConfigError
from rhi.master.runtime.pool import Workers, run_jobs

if TYPE_CHECKING:
    from rhi.components.vision.component import Decoder, GenerativeModel
# The decoders' modules load torch: each function below imports what it uses, so that a command refused while it
# checks its configuration (which imports this module) never pays for torch.

log = logging.getLogger("rhi.decoders")

KINDS = ("conv", "vae")  # the decoder slots of [decoder] and experiment.decoders
SHIPPED = Path(__file__).parent / "checkpoints"  # the default decoders, named as the cache names them


def cache_folder() -> Path:
    """The decoder cache: ``$RHI_CACHE``, or ``~/.cache/rhi`` when it is unset or empty."""
    return Path(os.environ.get("RHI_CACHE") or Path.home() / ".cache" / "rhi")


def checkpoint_path(kind: str, config: dict, must_exist: bool = False, device: str = "cpu") -> str:
    """The checkpoint of decoder ``kind``: the configured one, or the cached default (trained on ``device``,
    resolved: a decoder trained on a GPU has a name of its own)."""
    from rhi.master.decoders.training import train_settings

    given = config["decoder"].get(f"{kind}_checkpoint") or ""
    if given:
        problem = file_problem(given)
        if problem:
            raise ConfigError(f"decoder.{kind}_checkpoint: {given} {problem}")
        return given
    settings = train_settings(config).identity()
    blur = config["camera"]["blur"]
    # What changes the trained decoder: the [train] settings, and the camera's blur (the training images
    # have no ball, so ball_radius does not count), and a device other than the CPU (its rounding). The
    # default blur and the CPU add nothing, so the key of every decoder cached before they counted is unchanged.
    identity = [kind, settings] + ([{"camera_blur": blur}] if blur != camera.BLUR_SIGMA else []) + \
        ([{"device": device}] if device != "cpu" else [])
    key = hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:16]
    name = f"{kind}-r{settings['resolution']}-{settings['preset']}-{key}.pt"
    path = cache_folder() / name
    if not path.is_file() and (SHIPPED / name).is_file():
        return str(SHIPPED / name)
    if must_exist and not path.is_file():
        raise ConfigError(f"no trained {kind} decoder for these settings at {path}: run `rhi experiment` "
                          "once, or name a checkpoint in [decoder]")
    return str(path)


def shipped_pose_encoder(kind: str, resolution: int, stem: str = "pose-{kind}") -> Path:
    """The shipped pose encoder of decoder slot ``kind`` at ``resolution`` px: ``checkpoints/STEM-rRES.pt``, the
    stem a model's :attr:`~rhi.master.models.base.Model.pose_encoder_stem` (default ``pose-KIND``)."""
    return SHIPPED / f"{stem.format(kind=kind)}-r{resolution}.pt"


def pose_encoder_path(kind: str, config: dict) -> str:
    """The pose encoder of decoder slot ``kind``: the one the configuration names (``causal.<kind>_pose_encoder``,
    say), or else the model's shipped one at this resolution; ConfigError when there is none."""
    model = models.of(config)
    given = model.pose_encoder_file(kind, config)
    resolution = config["experiment"]["resolution"]
    path = Path(given) if given else shipped_pose_encoder(kind, resolution, model.pose_encoder_stem)
    if not path.is_file():
        what = f"no pose encoder at {path}" if given else \
            f"no shipped {kind} pose encoder at {resolution} px for the {model.name} model ({path})"
        key = model.pose_encoder_key.format(kind=kind)
        raise ConfigError(f"{what}: the brain or the reach's goal reads the seen arm's pose ("
                          + (f"name one in {key}, or " if key else "") + "make the shipped ones with "
                          "`python -m rhi.master.decoders.pose_encoders [--ownership] FOLDER`)")
    return str(path)


def check_decoders(config: dict, device: str = "cpu") -> None:
    """Before any work: every checkpoint named in ``[decoder]`` loads, is of its slot's kind and fits the
    camera (resolution, blur, ranges); every decoder still to be trained has valid ``[train]`` settings at
    this resolution and a usable cache folder; a model that reads a pose encoder has one for each slot. A ConfigError or CheckpointError (one line) otherwise.
    A checkpoint named for a decoder the experiment does not run is checked too: never silently ignored."""
    needs_training = []
    for kind in KINDS:
        if kind not in config["experiment"]["decoders"] and not config["decoder"].get(f"{kind}_checkpoint"):
            continue
        path = checkpoint_path(kind, config, device=device)
        if config["decoder"].get(f"{kind}_checkpoint"):
            check_kind(kind, path, loaded(path, config["experiment"]["resolution"], config["camera"]["blur"]))
        elif not Path(path).is_file():
            needs_training.append(kind)
    if needs_training:
        from rhi.master.decoders.training import train_settings

        train_settings(config)
        check_cache_folder()
    if models.of(config).sees_pose:  # the model reads the seen arm through a pose encoder of each slot
        for kind in config["experiment"]["decoders"]:
            pose_encoder_path(kind, config)


def check_kind(kind: str, path: str, model: GenerativeModel) -> None:
    """A checkpoint of another kind in the slot of ``kind`` is refused (a VAE's numbers are not conv's)."""
    from rhi.components.vision.checkpoint import CheckpointError

    trained = model.metadata.get("kind")
    if trained != kind:
        raise CheckpointError(f"{path}: a {trained} decoder, given as the {kind} decoder "
                              f"(decoder.{kind}_checkpoint / --{kind}-checkpoint); give a {kind} checkpoint")


def check_cache_folder() -> Path:
    """The decoder cache ($RHI_CACHE), created if missing, and writable: else one ConfigError naming it."""
    folder = cache_folder()
    where = f"the decoder cache {folder}" + (" (RHI_CACHE)" if os.environ.get("RHI_CACHE") else "")
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"{where} is not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        handle, probe = tempfile.mkstemp(dir=folder, prefix=".rhi-probe.")
        os.close(handle)
        os.unlink(probe)
    except OSError as error:
        raise ConfigError(f"{where} cannot be written: {error.strerror or error}") from None
    return folder


def ensure_checkpoints(config: dict, progress: bool = True, device: str = "cpu",
                       workers: Workers | None = None) -> tuple[dict[str, str], dict[str, float]]:
    """Every decoder the experiment needs, training (and caching) the missing defaults side by side on ``device``.

    The training set is rendered (or read from the cache) once, here; then each missing decoder trains
    in its own process. Returns the checkpoint of each decoder and the seconds spent: on the training
    set ("data") and training each decoder (its process's wall time, hand-error measure included).
    workers: train on these (left open) instead of workers of their own.
    """
    paths = {kind: checkpoint_path(kind, config, device=device) for kind in config["experiment"]["decoders"]}
    missing = [kind for kind, path in paths.items() if not Path(path).is_file()]
    if not missing:
        return paths, {}
    from rhi.master.decoders.training import prepare_data, train_decoder, train_settings

    began = time.perf_counter()
    settings, blur = train_settings(config), config["camera"]["blur"]
    prepare_data(check_cache_folder(), settings, blur, progress)
    seconds = {"data": time.perf_counter() - began}
    if progress:
        log.info(f"training the {' and '.join(missing)} decoder{'s' * (len(missing) > 1)} side by side "
                 f"({settings.preset}, {settings.resolution} px) into {cache_folder()}")
    processes = None
    if device != "cpu":  # one GPU: the decoders one after the other
        processes, workers = 1, None
    trained = run_jobs(train_decoder, [(kind, paths[kind], settings, False, blur, device) for kind in missing],
                       processes, workers)
    seconds.update({kind: sum(spent.values()) for kind, (_, spent) in zip(missing, trained)})
    return paths, seconds


def loaded(path: str, resolution: int, blur: float = camera.BLUR_SIGMA) -> GenerativeModel:
    """:func:`load_decoder`, once per file version and camera in this process (each load also renders the
    camera signature); the components never change the model, and the optimised copy is a deep copy."""
    return _loaded(path, os.stat(path).st_mtime_ns, resolution, blur)


@functools.lru_cache(maxsize=4)
def _loaded(path: str, version: int, resolution: int, blur: float) -> GenerativeModel:
    from rhi.master.decoders.training import load_decoder

    return load_decoder(path, resolution, blur)


def decoder_component(kind: str, path: str, config: dict, fast: bool | None = None,
                      threads: int | None = None, device: str = "cpu", name: str = "decoder") -> Decoder:
    """The exact decoder, or the linearised one of the fast mode when ``fast`` (default: ``decoder.fast``)
    is true; on ``threads`` torch threads (default: the usable cores) and on ``device``; component ``name``."""
    from rhi.components.vision.component import Decoder

    model = loaded(path, config["experiment"]["resolution"], config["camera"]["blur"])
    check_kind(kind, path, model)
    if config["decoder"]["fast"] if fast is None else fast:
        from rhi.components.vision.fast import LinearisedDecoder
        return LinearisedDecoder(model, name=name, relinearise_tolerance=config["decoder"]["relinearise_tolerance"],
                                 threads=threads, device=device)
    return Decoder(model, name=name, threads=threads, device=device)


def jacobian_pair(kind: str, path: str, config: dict) -> np.ndarray:
    """dg/d(shoulder) and dg/d(elbow) at the rest pose: (2, R, R), 1/deg."""
    from rhi.components.vision.component import jacobian_images

    model = loaded(path, config["experiment"]["resolution"], config["camera"]["blur"])
    return jacobian_images(model, np.array([kinematics.REST_POSE]))[0]


def per_decoder(config: dict, function, workers: Workers) -> tuple[dict[str, str], dict]:
    """Each decoder's checkpoint (trained if need be), then ``function(config, kind, checkpoint)`` for each decoder
    of the protocol, side by side on ``workers``: (checkpoints, {kind: result})."""
    checkpoints, _ = ensure_checkpoints(config, progress=True, workers=workers)
    kinds = config["experiment"]["decoders"]
    results = run_jobs(function, [(config, kind, checkpoints[kind]) for kind in kinds], workers=workers)
    return checkpoints, dict(zip(kinds, results))
