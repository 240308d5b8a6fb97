"""Training a decoder for the experiment, and loading one checked against today's camera.

Settings are ``[train]`` of the configuration (:func:`train_settings`), and the images are the
camera's at ``[camera] blur``, so `rhi train` and `rhi experiment` start from the same defaults.
The training data are rendered once per (samples, resolution, seed, blur) and cached beside the
checkpoint, so conv and vae trained into the same folder share them. With ``[train]
stop_hand_error_cm`` > 0 training stops once the hand error read off STOP_POSES held-out poses
(their own seed, quality.STOP_SEED) is at most that after an epoch.

Example::

    metadata, seconds = train_decoder("conv", "results/conv.pt", settings)   # blur=camera.BLUR_SIGMA
    model = load_decoder("results/conv.pt", resolution=64)
"""
from __future__ import annotations

import copy
import time
from pathlib import Path

import numpy as np
import torch

from rhi.components.body import camera, kinematics
from rhi.components.component import ComponentError
from rhi.components.vision import checkpoint, training
from rhi.components.vision.component import GenerativeModel, resolve_device
from rhi.components.vision.optimised import optimised
from rhi.master.cosim import ConfigError
from rhi.master.decoders import training_data
from rhi.master.decoders.quality import hand_error, read_off_error
from rhi.master.outputs.files import atomic_write
from rhi.master.outputs.out_file import check_output_file, place_file
from rhi.master.runtime.progress import bar

SIGNATURE_TOLERANCE = 1e-3  # relative; the signature moves by far more when the camera changes
STOP_POSES = 30             # held-out poses of the hand-error check that may stop training (a few s at 256 x 256)


def train_settings(config: dict) -> training.TrainSettings:
    """TrainSettings from ``[train]``, at the experiment's resolution."""
    try:
        return training.TrainSettings(**{**config.get("train", {}),
                                         "resolution": config["experiment"]["resolution"]})
    except (TypeError, ComponentError) as error:  # TypeError: an unknown key
        raise ConfigError(f"[train]: {error}") from None


def check_target(out) -> Path:
    """CKPT (a name ending in .pt) as a Path if a checkpoint can be written there, checked before any
    training: an existing file is replaced only if it is a decoder checkpoint itself."""
    out = check_output_file(out, "checkpoint file")
    if out.suffix != ".pt" or out.name == ".pt":
        raise ConfigError(f"--out {str(out)!r} must be a file name ending in .pt")
    if out.exists():
        try:
            checkpoint.read_metadata(out)
        except checkpoint.CheckpointError:
            raise ConfigError(f"--out {out} exists and is not a decoder checkpoint; it is never replaced: move it "
                              "or choose another name") from None
    return out


def data_path(folder: Path, settings: training.TrainSettings, blur: float = camera.BLUR_SIGMA) -> Path:
    """The cached data set's file: the default camera's name has no blur in it (files made before the
    blur was a parameter stay valid); another blur has its own file."""
    blurred = "" if blur == camera.BLUR_SIGMA else f"-b{blur!r}"
    return folder / f"decoder-data-r{settings.resolution}-n{settings.samples}-s{settings.seed}{blurred}.npz"


def prepare_data(folder: Path, settings: training.TrainSettings, blur: float = camera.BLUR_SIGMA,
                 progress: bool = False) -> training_data.TrainingData:
    """The training set of ``settings`` at ``blur``, read from ``folder``'s cache or rendered into it."""
    return training_data.cached(data_path(folder, settings, blur), settings.samples, settings.resolution,
                                settings.seed, progress, blur)


def hand_error_check(rest_pose, half_ranges, blur: float = camera.BLUR_SIGMA):
    """The check :func:`training.train` calls after each epoch: the mean hand error (cm) read off the
    decoder's predictions at STOP_POSES held-out poses, on a CPU copy of it (the training's is left as it is)."""
    def check(decoder) -> float:
        copied = copy.deepcopy(decoder).to("cpu", memory_format=torch.contiguous_format)
        return read_off_error(GenerativeModel(copied, rest_pose, half_ranges), STOP_POSES, blur=blur)
    return check


def train_decoder(kind: str, out: str | Path, settings: training.TrainSettings | None = None,
                  progress: bool = True, blur: float = camera.BLUR_SIGMA, device: str = "cpu") -> tuple[dict, dict]:
    """Train a decoder of ``kind`` on camera images blurred by ``blur`` m and save it to ``out``.

    device: cpu, cuda or auto (:func:`resolve_device`); the metadata names it when it is not the CPU.
    Returns the checkpoint metadata (with the camera's blur and signature) and the wall time of each
    part, s (data, training, quality), which the checkpoint does not store.
    """
    settings = settings or training.TrainSettings()
    device = resolve_device(device)
    out = check_target(out)
    started = time.perf_counter()
    data = prepare_data(out.parent, settings, blur, progress)
    seconds = {"data": time.perf_counter() - started}
    check = hand_error_check(data.rest_pose, data.half_ranges, blur) if settings.stop_hand_error_cm else None
    model, report = training.train(kind, data.poses, data.images, data.rest_pose, data.half_ranges, settings,
                                   progress and bar, device=device, check=check)
    seconds["training"] = report["seconds"]
    metadata = training.checkpoint_metadata(kind, settings, data.rest_pose, data.half_ranges,
                                            data.content_hash, report)
    if device != "cpu":  # a CPU-trained checkpoint's metadata is as before devices existed
        metadata["device"] = device
    metadata["camera_blur"] = float(blur)
    metadata["camera_signature"] = training_data.camera_signature(settings.resolution, blur)
    if settings.quality_poses:
        began = time.perf_counter()
        measured = GenerativeModel(model.decoder, data.rest_pose, data.half_ranges)
        if device != "cpu":
            measured = measured.on(device)
        elif settings.channels_last:  # the fit's Jacobians through the CPU-optimised copy (channels-last too)
            measured = optimised(measured)
        metadata["hand_error"] = hand_error(measured, settings.quality_poses, blur=blur)
        seconds["quality"] = time.perf_counter() - began
    atomic_write(out, lambda file: checkpoint.write(file, model, metadata), place_file)  # not over a newcomer
    return metadata, seconds


def load_decoder(path: str | Path, resolution: int, blur: float = camera.BLUR_SIGMA) -> GenerativeModel:
    """A trained decoder checked against today's camera at ``resolution`` and ``blur`` (m) and the body's
    rest pose and training ranges: CheckpointError (a ValueError naming the file) on any mismatch.
    A checkpoint without a stored camera_blur was trained before the blur was a parameter, at the default."""
    model = GenerativeModel.from_checkpoint(path, resolution, kinematics.REST_POSE, training_data.HALF_RANGES)
    trained_blur = model.metadata.get("camera_blur", camera.BLUR_SIGMA)
    if trained_blur != blur:
        raise checkpoint.CheckpointError(f"{path}: trained on camera images blurred by {trained_blur} m, but "
                                         f"camera.blur is {blur} m; retrain the decoder or set camera.blur")
    stored = model.metadata.get("camera_signature")
    if stored is not None:
        now = training_data.camera_signature(resolution, blur)
        if len(stored) != len(now) or not np.allclose(stored, now, rtol=SIGNATURE_TOLERANCE, atol=1e-6):
            raise checkpoint.CheckpointError(f"{path}: trained on images of another camera (its field of view "
                                             "or drawing changed since); retrain the decoder")
    return model
