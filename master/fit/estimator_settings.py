"""``fit.estimator``: the conditional flow's settings, their defaults (sbi's own), choices and limits, and the memory
its training needs, checked before any simulation."""
from __future__ import annotations

import math

from rhi.master import config as configuration
from rhi.master.cosim import ConfigError
from rhi.master.fit.priors import MAX_SIMULATIONS

# the flow's size, batch and learning rate are sbi's own defaults (posterior_nn, NPE.train)
ESTIMATOR_DEFAULTS = {"density": "maf", "hidden_features": 50, "transforms": 5, "batch_size": 200,
                      "max_epochs": 500, "learning_rate": 5e-4, "threads": 2, "ensemble": 1, "space": "unconstrained",
                      "statistics": "normal-scores"}
CHOICES = {"density": ("maf", "nsf", "mdn"), "space": ("bounded", "unconstrained"),
           "statistics": ("z-score", "normal-scores")}
# The largest value of each whole-number estimator key (docs/safety.md): a flow twenty times sbi's width (50) and
# about thirteen times its depth (5) is far beyond what MAX_SIMULATIONS participants can train; an ensemble of 32;
# a batch of every simulation; 100 000 epochs (early stopping ends sbi's training long before); torch's threads
# bounded as train.threads is. A learning rate above 1 moves each weight by more than its initial scale per step.
MAX_ESTIMATOR = {"hidden_features": 1024, "transforms": 64, "batch_size": MAX_SIMULATIONS, "max_epochs": 100_000,
                 "threads": configuration.MAX_THREADS, "ensemble": 32}
MAX_LEARNING_RATE = 1.0
# Weights per transform of sbi's flows, at most this many times hidden x (hidden + parameters + statistics + 1)
# (measured on maf, nsf and mdn, 1 to 16 parameters and 1 to 24 statistics: at most 6.1); bytes per weight in
# training: the weight, its gradient and Adam's two moments, float32; bytes of activations kept for the backward
# pass per batch row, transform and hidden unit (measured in one training step: maf 43, nsf 87, mdn 31).
FLOW_WEIGHTS_FACTOR = 8
BYTES_PER_TRAINED_WEIGHT = 16
ACTIVATION_BYTES = 128


def read_estimator(table, parameters: int, statistics: int) -> dict:
    """``fit.estimator`` checked (:func:`check_estimator_key`, :func:`check_estimator_memory` for ``parameters``
    fitted on ``statistics`` statistics), the defaults filled in."""
    if not isinstance(table, dict):
        raise ConfigError("fit.estimator must be a table")
    for key, value in table.items():
        if key not in ESTIMATOR_DEFAULTS:
            raise configuration.unknown_key(f"fit.estimator.{key}", ESTIMATOR_DEFAULTS, "fit")
        check_estimator_key(key, value)
    chosen = {**ESTIMATOR_DEFAULTS, **table}
    check_estimator_memory(chosen, parameters, statistics)
    return chosen


def check_estimator_key(key: str, value) -> None:
    """One ``fit.estimator`` key: one of its choices, or a number of its type within (0, its maximum]."""
    default = ESTIMATOR_DEFAULTS[key]
    if isinstance(default, str):
        if value not in CHOICES[key]:
            raise ConfigError(f"fit.estimator.{key} = {str(value)[:60]!r} is not one of {', '.join(CHOICES[key])}")
        return
    if (not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0 or not math.isfinite(value)
            or (isinstance(default, int) and not isinstance(value, int))):
        raise ConfigError(f"fit.estimator.{key} = {value!r} must be a positive "
                          f"{'whole number' if isinstance(default, int) else 'finite number'}")
    top = MAX_ESTIMATOR.get(key, MAX_LEARNING_RATE)
    if value > top:
        raise ConfigError(f"fit.estimator.{key} = {value!r} is over the limit of {top:g} ({ESTIMATOR_LIMITS_WHY[key]})")


ESTIMATOR_LIMITS_WHY = {
    "hidden_features": "about twenty times sbi's 50: wider than the most simulations a fit runs can train",
    "transforms": "about thirteen times sbi's 5: deeper than the most simulations a fit runs can train",
    "batch_size": f"fit.simulations is at most {MAX_SIMULATIONS}: one batch of them all",
    "max_epochs": "sbi's early stopping ends a training long before",
    "threads": "twice the hardware threads of the largest common server, as train.threads",
    "ensemble": "each member is one more training of the whole estimator",
    "learning_rate": "a step that moves each weight by more than its initial scale: the loss diverges"}


def estimator_memory(settings: dict, parameters: int, statistics: int) -> int:
    """About how many bytes training the estimators of ``settings`` needs at its peak: every ensemble member's
    weights (with their gradients and Adam's moments) and one batch's activations (FLOW_WEIGHTS_FACTOR and the
    bytes above: upper bounds, to refuse what cannot fit, not to plan)."""
    hidden, transforms = settings["hidden_features"], settings["transforms"]
    weights = FLOW_WEIGHTS_FACTOR * transforms * hidden * (hidden + parameters + statistics + 1)
    activations = settings["batch_size"] * transforms * hidden * ACTIVATION_BYTES
    return settings["ensemble"] * weights * BYTES_PER_TRAINED_WEIGHT + activations


def check_estimator_memory(settings: dict, parameters: int, statistics: int) -> None:
    """A ConfigError, before any simulation, for an estimator whose training needs more memory than this machine
    has, saying how much."""
    needed, available = estimator_memory(settings, parameters, statistics), configuration.physical_memory()
    if available and needed > available:
        raise ConfigError(f"training the estimator would need about {configuration.size(needed)} of memory "
                          f"({settings['ensemble']} x a {settings['density']} of {settings['transforms']} transforms "
                          f"of {settings['hidden_features']} hidden features, batches of {settings['batch_size']}), "
                          f"more than this machine's {configuration.size(available)}; lower fit.estimator."
                          "hidden_features, transforms, ensemble or batch_size")
