"""Fast stand-ins for rhi.master.tasks.illusion.trial_outcome, importable by Dask workers (repo root on PYTHONPATH).

``fake_outcome`` is a closed-form function of the configuration and the trial's seed, so a test can
compute every trial's exact result itself. It places the rubber hand by inverse kinematics, so an
offset out of the arm's reach fails as the real experiment would, and its outcome means what the real
one means (tests/test_contracts.py): drift and force toward the rubber hand, gamma higher for
synchronous touch.
"""
import time

import numpy as np

from rhi.components.body import kinematics
from rhi.master.tasks.illusion import trial_seed

SLOW_TRIAL_S = 0.4


def fake_outcome(config: dict, decoder: str, condition: str, stimulation: str, index: int) -> dict:
    offset = config["conditions"][condition]
    kinematics.inverse(kinematics.REST_HAND[0] + offset, kinematics.REST_HAND[1])  # ValueError when out of reach
    seed = trial_seed(config["experiment"]["seed"], condition, stimulation, index)
    noise = np.random.default_rng(seed).normal()
    delay = config["stimulations"][stimulation]["delay_max"]
    gain = 0.5 if decoder == "vae" else 0.4
    return {"drift_cm": 100.0 * gain * offset * np.exp(-delay / 0.3) + 0.1 * noise,
            "force_n": 2.0 * offset * np.exp(-delay / 0.3),
            "gamma_final": float(np.exp(-delay))}


def faulty_outcome(config: dict, decoder: str, condition: str, stimulation: str, index: int) -> dict:
    """fake_outcome, but a fault on demand: every trial whose rubber hand lies right of the real one fails
    (a configuration the checks accept, unlike a hand out of reach, which is refused before any trial runs)."""
    if config["conditions"][condition] > 0:
        raise ValueError(f"a fault on demand: offset {config['conditions'][condition]} m > 0")
    return fake_outcome(config, decoder, condition, stimulation, index)


def slow_outcome(config: dict, decoder: str, condition: str, stimulation: str, index: int) -> dict:
    time.sleep(SLOW_TRIAL_S)
    return fake_outcome(config, decoder, condition, stimulation, index)


def stuck_outcome(config: dict, decoder: str, condition: str, stimulation: str, index: int) -> dict:
    """Touches $RHI_TEST_STUCK_MARKER, then holds the GIL in native code for a minute (libc's sleep through
    ctypes.PyDLL, which keeps the GIL), as a native call that never returns would: no Python thread of the
    worker runs meanwhile, so only the kernel can end it."""
    import ctypes
    import os

    open(os.environ["RHI_TEST_STUCK_MARKER"], "w").close()
    ctypes.PyDLL(None).sleep(60)
    return fake_outcome(config, decoder, condition, stimulation, index)


def wordy_outcome(config: dict, decoder: str, condition: str, stimulation: str, index: int) -> dict:
    """fake_outcome, but its drift in words where a number belongs: every trial whose rubber hand lies right of the
    real one says "lots"."""
    outcome = fake_outcome(config, decoder, condition, stimulation, index)
    return {**outcome, "drift_cm": "lots"} if config["conditions"][condition] > 0 else outcome
