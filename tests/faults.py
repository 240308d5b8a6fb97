"""Faults on demand for the reliability tests: body plants that misbehave (NaN, a step that hangs, a step
stuck with its signals blocked), exported as FMUs, and tiny decoder checkpoints, made once per module."""
from __future__ import annotations

import os
import shutil
import zipfile
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}

FAULTY_PLANTS = '''
import itertools, os, signal, time
import numpy as np
from components.body.plant import ArmPlant

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


def make_resources(folder: Path) -> Resources:
    """Tiny conv and VAE checkpoints at 32 px and the FMUs above, made in ``folder``."""
    from components.vision.training import TrainSettings
    from master.experiment.training import train_decoder
    from master.export.body import build_fmu

    settings = TrainSettings(preset="tiny", samples=40, epochs=1, batch_size=20, resolution=32, quality_poses=0,
                             threads=1)
    checkpoints = {}
    for kind in ("conv", "vae"):
        checkpoints[kind] = str(folder / f"tiny-{kind}.pt")
        train_decoder(kind, checkpoints[kind], settings, progress=False)
    plants = folder / "rhi_test_faulty_plants.py"
    plants.write_text(FAULTY_PLANTS)
    fmus = {"native": str(build_fmu(folder / "native.fmu", "native"))}
    for name in ("NanThirdArmPlant", "HangingArmPlant", "DeafArmPlant"):
        fmus[name] = str(build_fmu(folder / f"{name}.fmu", component=f"rhi_test_faulty_plants:{name}",
                                   model_name=name, extra_files=[plants]))
    fmus["HangingArmPlant-b"] = str(shutil.copy(fmus["HangingArmPlant"], folder / "HangingArmPlant-b.fmu"))
    fmus["unloadable"] = str(folder / "Unloadable.fmu")
    with zipfile.ZipFile(fmus["native"]) as old, zipfile.ZipFile(fmus["unloadable"], "w") as new:
        for item in old.infolist():
            new.writestr(item, b"not a shared library\n" * 400 if item.filename.endswith(".so") else old.read(item))
    return Resources(folder, checkpoints["conv"], checkpoints["vae"], fmus)
