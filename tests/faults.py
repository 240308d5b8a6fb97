"""Faults on demand for the reliability tests: body plants that misbehave (NaN, a step that hangs, a step
stuck with its signals blocked), exported as FMUs, and tiny decoder checkpoints, made once per module."""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}

FAULTY_PLANTS = '''
import itertools, os, signal, time
import numpy as np
from rhi.components.body.plant import ArmPlant

_made = itertools.count()  # instances made in this process, across FMU instances of one FMU


class _Third(ArmPlant):
    """The third instance made in a process misbehaves from t = 0.1 s on (the first batch's trial 2)."""
    def instantiate(self, batch_size=1):
        super().instantiate(batch_size)
        self.number = next(_made)

    def faulty(self, t):
        return self.number == 2 and t >= 0.1 - 1e-9


class NanThirdArmPlant(_Third):
    def step(self, t, h):
        super().step(t, h)
        if self.faulty(t):
            self.values["hand_y"] = np.full(self.batch_size, np.nan)


class HangingArmPlant(_Third):
    """Blocks in its step (an hour), after touching $RHI_TEST_HANG_MARKER."""
    def step(self, t, h):
        if self.faulty(t):
            marker = os.environ.get("RHI_TEST_HANG_MARKER")
            if marker:
                open(marker, "w").close()
            time.sleep(3600)
        super().step(t, h)


class DeafArmPlant(_Third):
    """Blocks in its step with every signal blocked, as native code that never returns would."""
    def step(self, t, h):
        if self.faulty(t):
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM, signal.SIGINT, signal.SIGTERM})
            time.sleep(3600)
        super().step(t, h)
'''


# -- shared resources: tiny checkpoints and FMUs, made once ---------------------------------------------
@dataclass
class Resources:
    folder: Path
    conv: str          # a tiny conv decoder at 32 px (what --quick renders)
    vae: str           # a tiny VAE at 32 px
    fmus: dict         # name -> path: native, NanThirdArmPlant, HangingArmPlant, DeafArmPlant, unloadable


def resources_at(folder: Path) -> Resources:
    """The paths :func:`make_resources` writes in ``folder``."""
    names = ("native", "NanThirdArmPlant", "HangingArmPlant", "DeafArmPlant", "HangingArmPlant-b")
    fmus = {name: str(folder / f"{name}.fmu") for name in names}
    fmus["unloadable"] = str(folder / "Unloadable.fmu")
    return Resources(folder, str(folder / "tiny-conv.pt"), str(folder / "tiny-vae.pt"), fmus)


def make_resources(folder: Path) -> Resources:
    """Tiny conv and VAE checkpoints at 32 px and the FMUs above, made in ``folder``."""
    from rhi.components.vision.training import TrainSettings
    from rhi.master.decoders.training import train_decoder
    from rhi.master.export.body import build_fmu

    made = resources_at(folder)
    settings = TrainSettings(preset="tiny", samples=40, epochs=1, batch_size=20, resolution=32, quality_poses=0,
                             threads=1)
    for kind in ("conv", "vae"):
        train_decoder(kind, getattr(made, kind), settings, progress=False)
    plants = folder / "rhi_test_faulty_plants.py"
    plants.write_text(FAULTY_PLANTS)
    fmus = made.fmus
    build_fmu(fmus["native"], "native")
    for name in ("NanThirdArmPlant", "HangingArmPlant", "DeafArmPlant"):
        build_fmu(fmus[name], component=f"rhi_test_faulty_plants:{name}", model_name=name, extra_files=[plants])
    shutil.copy(fmus["HangingArmPlant"], fmus["HangingArmPlant-b"])
    with zipfile.ZipFile(fmus["native"]) as old, zipfile.ZipFile(fmus["unloadable"], "w") as new:
        for item in old.infolist():
            new.writestr(item, b"not a shared library\n" * 400 if item.filename.endswith(".so") else old.read(item))
    return made


def snapshot(folder: Path) -> dict:
    """Every entry under ``folder``, hidden ones too: relative path -> (kind, size, content hash) or the link."""
    found = {}
    for path in sorted(folder.rglob("*")):
        key = str(path.relative_to(folder))
        if path.is_symlink():
            found[key] = ("link", os.readlink(path))
        elif path.is_dir():
            found[key] = ("folder",)
        else:
            found[key] = ("file", path.stat().st_size, hashlib.sha256(path.read_bytes()).hexdigest())
    return found


def rhi(root: Path, *args, timeout=60, own_process=False, python=None):
    """``rhi ARGS`` with cwd root/work, TMPDIR root/tmp and RHI_CACHE root/cache: in this process (tests.in_process:
    a refusal then costs milliseconds, not the seconds of a fresh interpreter importing torch), or with
    ``own_process`` in a subprocess, for a run that may hang (its timeout is the check), talks to a listener,
    starts a child process, or would, were a bound missing, allocate or start threads without end. ``python``
    (own process only): ``python -c`` this instead of ``python -m rhi``, ARGS its sys.argv[1:] (a module's
    constant set before main() runs). A CompletedProcess either way."""
    for name in ("work", "tmp", "cache"):
        (root / name).mkdir(parents=True, exist_ok=True)
    arguments = [*map(str, args)]
    if not own_process:
        from tests.in_process import rhi_in_process

        done = rhi_in_process(arguments, root / "work", {"TMPDIR": str(root / "tmp"), "RHI_CACHE": str(root / "cache")},
                              timeout=timeout)
        return subprocess.CompletedProcess(["rhi", *arguments], done.status, done.stdout, done.stderr)
    env = {**ENV, "TMPDIR": str(root / "tmp"), "RHI_CACHE": str(root / "cache")}
    start = ["-c", python] if python is not None else ["-m", "rhi"]
    return subprocess.run([sys.executable, *start, *arguments], cwd=root / "work", env=env,
                          capture_output=True, text=True, timeout=timeout)


def refused(done, says: str) -> None:
    """Exit status 2, one line on stderr holding ``says``, no traceback."""
    shown = f"status {done.returncode}, stderr {done.stderr[-800:]!r}"
    assert done.returncode == 2, shown
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0] and "Traceback" not in done.stderr, shown


def tiny_checkpoint(path: Path, **changes) -> Path:
    """A decoder checkpoint of the tiny preset at 16 px, untrained (weights as built), metadata ``changes``d."""
    from rhi.components.vision import checkpoint
    from rhi.components.vision.networks import build, preset, sizes_dict

    model = build("conv", "tiny", 16)
    metadata = {"kind": "conv", "preset": "tiny", "sizes": sizes_dict(preset("tiny")), "resolution": 16,
                "rest_pose": [147.7, -91.2], "half_ranges": [30.0, 30.0], "data_hash": "x", "validation_mse": 0.1}
    for key, value in changes.items():
        if key.startswith("sizes."):
            metadata["sizes"][key[6:]] = value
        else:
            metadata[key] = value
    with open(path, "wb") as file:
        checkpoint.write(file, model, metadata)
    return path


CONV_ONLY = '[experiment]\ndecoders = ["conv"]\n'


def experiment(*args, config="conv_only.toml", ckpt=True, steps="20"):
    """`rhi experiment --quick` with the tiny conv decoder, conv only, a few steps."""
    return (["experiment", "--quick", "--config", config] + (["--conv-checkpoint", "{conv}"] if ckpt else [])
            + (["--steps", steps] if steps else []) + list(args))


def expand(argument: str, resources: Resources) -> str:
    names = {"{conv}": resources.conv, "{vae}": resources.vae,
             **{f"{{fmu:{name}}}": path for name, path in resources.fmus.items()}}
    return names.get(argument, argument)
