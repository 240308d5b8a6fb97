"""What ``rhi bench`` measures and how long (:class:`BenchSettings`, :data:`QUICK` for smoke tests), and the
pieces every measurement shares: untrained decoders, the protocol's configuration and trials, a timer."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from rhi.components.body import kinematics
from rhi.components.vision.component import GenerativeModel
from rhi.components.vision.fast import DEFAULT_TOLERANCE
from rhi.components.vision.networks import build
from rhi.master.tasks import illusion as experiment
from rhi.master import config as configuration
from rhi.master.decoders.training_data import HALF_RANGES


@dataclass(frozen=True)
class BenchSettings:
    """What ``rhi bench`` measures and for how long (each field's comment says what it sets; :data:`QUICK`: a
    smoke test's).
    """
    presets: tuple = (("paper", 256), ("default", 64))  # (network preset, resolution)
    batch: int = 60              # trials in lockstep: the whole protocol (2 decoders x 3 x 2 x 5)
    max_steps: int = 50          # measured steps per mode at most ...
    min_steps: int = 2           # ... and at least
    budget_s: float = 8.0        # aimed-at measuring time per mode
    protocol_steps: int = 1500   # the fast-mode run of the whole paper protocol
    protocol_preset: tuple = ("paper", 256)
    protocol_trained: str = "paper"  # whose cached trained decoders run the protocol when both are cached:
                                     # "paper" (--preset paper), "quick" (--quick); "": always the untrained one
    tolerance: float = DEFAULT_TOLERANCE
    error_trials: int = 5        # per condition x stimulation, for the fast mode's drift error (as in one
                                 # decoder's half of the protocol)
    error_steps: int = 1500
    error_model: str = "cached"  # cached: the trained default conv decoder (or error_checkpoint); untrained: tiny
    error_checkpoint: str = ""   # a trained conv checkpoint at the default resolution, instead of the cached one
    fmu_steps: int = 300
    matmul_size: int = 2048
    threads: int = 0             # torch threads; 0: the cores this process may use
    seed: int = 0
    default_run: bool = True     # time `rhi experiment` from an empty decoder cache (master/bench/default_run.py)
    sweep_preset: tuple = ("default", 64)  # the sweep against lockstep (master/bench/sweep_rate.py)
    sweep_trials: int = 5        # per decoder x condition x stimulation: 60 trials, the whole protocol
    sweep_steps: int = 1500
    sweep_trained: bool = True   # the trained default decoders (shipped) rather than untrained ones
    sweep_workers: int = 0       # the sweep's local pool; 0: one per usable core
    fit_preset: tuple = ("default", 64)  # the fit's unit of work (master/bench/fit_unit.py)
    fit_models: tuple = ("paper", "causal")  # its baseline, then the model whose cost is compared with it
    fit_trained: bool = True     # the trained default conv decoder and shipped pose encoder rather than untrained ones
    fit_participants: int = 10   # per lockstep batch: fit.participants_per_batch's default
    fit_batches: int = 2         # one after another: the first pays for every picture, the next finds them kept
    fit_steps: int = 1500


QUICK = BenchSettings(presets=(("tiny", 32),), batch=6, max_steps=3, budget_s=0.5, protocol_steps=10,
                      protocol_preset=("tiny", 32), protocol_trained="", error_trials=1, error_steps=30,
                      error_model="untrained", fmu_steps=20, matmul_size=256, default_run=False,
                      sweep_preset=("tiny", 32), sweep_trials=1, sweep_steps=10, sweep_workers=1, sweep_trained=False,
                      fit_preset=("tiny", 32), fit_trained=False, fit_participants=2, fit_steps=10)


def untrained(preset: str, resolution: int, seed: int) -> GenerativeModel:
    """An untrained conv decoder, seeded (the speed does not depend on the weights).

    Parameters
    ----------
    preset : str
        The network preset (:data:`rhi.components.vision.networks.PRESETS`).
    resolution : int
        Image side, px.
    seed : int
        torch's seed for the initial weights.

    Returns
    -------
    GenerativeModel
        About the rest pose and the training data's half-ranges, as a trained one.
    """
    torch.manual_seed(seed)
    return GenerativeModel(build("conv", preset, resolution).decoder, kinematics.REST_POSE, HALF_RANGES)


def protocol_config(resolution: int, steps: int, **overrides) -> dict:
    """The experiment configuration the bench runs: the defaults at ``resolution`` px for ``steps`` steps with
    both decoders, and ``overrides`` (dotted keys) on top.
    """
    return configuration.load(overrides={"experiment.resolution": resolution, "experiment.steps": steps,
                                         "experiment.decoders": ["conv", "vae"], **overrides})


def protocol_trials(config: dict, batch: int) -> list:
    """``batch`` trials of the protocol's plan, spread over it (all 60 when batch is 60)."""
    trials = experiment.plan(config)
    return [trials[i] for i in np.linspace(0, len(trials) - 1, batch).round().astype(int)]


def timed(function):
    """``function()``'s value and its wall time, s.

    Returns
    -------
    value : object
        What ``function()`` returned.
    seconds : float
        Its wall time (``time.perf_counter``).
    """
    began = time.perf_counter()
    value = function()
    return value, time.perf_counter() - began
