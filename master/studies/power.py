"""The power of a within-participant contrast (``rhi power``): K simulated studies of n participants each, a paired
t test per study at alpha, the power the share of studies that reject, with its Monte Carlo standard error.

In memory, any simulator of paired measures is a study::

    from rhi.master.studies import power
    curve = power.power(power.protocol_simulator(config, ("sync", "async")), ns=(10, 20, 40), studies=200)
    curve[0].power, curve[0].mc_error          # n = 10

A study of the model (:func:`protocol_simulator`) is a fresh cohort (its own master seed, so its own participants,
drawn from the configuration's ``[population]``), each participant running both sides of the contrast, all of a
study's trials in one lockstep batch. The studies of each smaller n are the first n participants of the same
studies (nested cohorts): each point of the curve is an unbiased estimate with the stated error, and neighbouring
points are correlated.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import stats

from rhi.master import config as configuration
from rhi.master.cosim import ConfigError

ALPHA = 0.05  # the conventional two-sided level a paper would test the contrast at


@dataclass(frozen=True)
class PowerPoint:
    """The power at one study size.

    Attributes
    ----------
    n : int
        Participants per study.
    studies : int
        Simulated studies, K.
    power : float
        The share of studies whose paired t test rejects at ``alpha``.
    mc_error : float
        Its Monte Carlo standard error, sqrt(p (1 - p) / K).
    mean_difference : float
        The contrast's mean difference (first side minus second), averaged over the studies.
    sd_difference : float
        The between-participant sd of the difference, averaged over the studies.
    """

    n: int
    studies: int
    power: float
    mc_error: float
    mean_difference: float
    sd_difference: float


def monte_carlo_error(power: float, studies: int) -> float:
    """The standard error of a proportion ``power`` estimated from ``studies`` independent studies, each a
    Bernoulli trial: sqrt(p (1 - p) / K) (the binomial proportion's standard error)."""
    return math.sqrt(power * (1.0 - power) / studies)


def rejects(first: np.ndarray, second: np.ndarray, alpha: float) -> bool:
    """Whether the two-sided paired t test (scipy.stats.ttest_rel; pairs with a missing value left out) rejects
    equal means at ``alpha``; a test with no variance and no difference (p undefined) does not."""
    p = stats.ttest_rel(first, second, nan_policy="omit").pvalue
    return bool(np.isfinite(p) and p < alpha)


def power(simulate: Callable[[int, int], tuple[np.ndarray, np.ndarray]], ns, studies: int,
          alpha: float = ALPHA) -> list[PowerPoint]:
    """The power curve over study sizes ``ns``.

    Parameters
    ----------
    simulate : callable
        ``simulate(study, n)`` -> (first, second): each (n,) the measure of the study's n participants under the
        two sides of the contrast (NaN where a trial failed). The same ``study`` gives the same participants.
    ns : sequence of int
        Participants per study, each at least 2.
    studies : int
        K, simulated studies per size (the larger sizes' first participants make the smaller ones').
    alpha : float
        The test's level.
    """
    ns = [int(n) for n in ns]
    if not ns or min(ns) < 2:
        raise ConfigError(f"power: every study size must be at least 2 participants (a paired t test), got {ns}")
    if studies < 1:
        raise ConfigError(f"power: simulate at least 1 study, got {studies}")
    pairs = [tuple(np.asarray(side, dtype=float) for side in simulate(study, max(ns))) for study in range(studies)]
    curve = []
    for n in ns:
        rejected = [rejects(first[:n], second[:n], alpha) for first, second in pairs]
        differences = [first[:n] - second[:n] for first, second in pairs]
        share = float(np.mean(rejected))
        curve.append(PowerPoint(n, studies, share, monte_carlo_error(share, studies),
                                float(np.mean([np.nanmean(d) for d in differences])),
                                float(np.mean([np.nanstd(d, ddof=1) for d in differences]))))
    return curve


def study_seed(master_seed: int, study: int) -> int:
    """A stable 63-bit master seed per simulated study: a fresh cohort, fresh delays."""
    digest = hashlib.sha256(f"{master_seed}/study/{study}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


def parse_contrast(text: str, config: dict) -> tuple[str, str]:
    """``"sync-async"`` -> ("sync", "async"): two stimulations the configuration defines; ConfigError otherwise."""
    first, dash, second = text.partition("-")
    if not dash or not first or not second or first == second:
        raise ConfigError(f"--contrast {text!r}: give two different stimulations as A-B, e.g. sync-async")
    for name in (first, second):
        if name not in config["stimulations"]:
            raise ConfigError(f"--contrast {text!r}: {name!r} is not a stimulation of the configuration (one of "
                              f"{', '.join(config['stimulations'])})")
    return first, second


def study_config(config: dict, contrast: tuple[str, str], n: int, study: int, condition: str, decoder: str) -> dict:
    """The configuration of one study: its own master seed, n participants, the contrast's two stimulations in
    ``condition`` with ``decoder``, all in one lockstep batch."""
    merged = configuration.merge(config, {"experiment": {
        "seed": study_seed(config["experiment"]["seed"], study), "trials": n, "conditions": [condition],
        "stimulations": list(contrast), "decoders": [decoder], "batch_trials": 0}})
    configuration.validate(merged)
    return merged


def protocol_simulator(config: dict, contrast: tuple[str, str], measure: str = "drift_cm",
                       condition: str | None = None, decoder: str | None = None, context=None, workers=None):
    """``simulate(study, n)`` for :func:`power`: the model's protocol of one study (:func:`study_config`; condition
    and decoder default to the configuration's first), the end-of-trial ``measure`` of each participant under each
    side. The decoders are trained (or found) and the fast mode checked once, on ``config``."""
    from rhi.master.decoders.cache import ensure_checkpoints
    from rhi.master.tasks.illusion import runner
    from rhi.master.tasks.illusion.fast_check import verdicts
    from rhi.master.tasks.illusion.measures import end_of_trial

    condition = condition or config["experiment"]["conditions"][0]
    decoder = decoder or config["experiment"]["decoders"][0]
    if condition not in config["conditions"]:
        raise ConfigError(f"--condition {condition!r} is not a condition of the configuration")
    base = study_config(config, contrast, 2, 0, condition, decoder)
    checkpoints, _ = ensure_checkpoints(base, progress=False, workers=workers)
    fast = {kind: mode["fast"] for kind, mode in verdicts(base, checkpoints, workers).items()}

    def simulate(study: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        own = study_config(config, contrast, n, study, condition, decoder)
        trials, times, per_step, _, _ = runner.run(own, checkpoints, None, context, fast=fast, workers=workers)
        final = end_of_trial(times, per_step)
        if measure not in final:
            raise ConfigError(f"--measure {measure!r} is not a measure of the model (one of {', '.join(final)})")
        sides = np.full((2, n), np.nan)
        for position, trial in enumerate(trials):
            sides[contrast.index(trial.stimulation), trial.index] = final[measure][position]
        return sides[0], sides[1]

    return simulate
