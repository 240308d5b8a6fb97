"""The fit's unit of work, for ``rhi bench``: CPU-s per simulated 1500-step trial in a fit-like lockstep batch, for
the paper's model and the causal one, measured in one run, and their ratio.

A fit (master/fit/simulate.py) runs its simulated participants in lockstep batches of ``fit.participants_per_batch``
participants, each with its own draw of the fitted parameters and its own seed, over every design cell, one trial a
cell; a worker runs a batch with :func:`rhi.master.tasks.illusion.runner.batch_outcomes` (master/sweeps/runner.py,
``run_chunk``). Here the same: ``fit_participants`` participants a batch over the protocol's cells (every condition x
stimulation of the defaults, the conv decoder), ``fit_batches`` batches one after another in this process, each
participant's values drawn from :data:`PRIORS` (uniform, or log-uniform: uniform in the logarithm, as
``rhi.master.fit.plan.draw_prior`` draws them), the batches' trial counts and steps the fit's.

CPU-s is this process's CPU time (``time.process_time``: every thread of it; the batches run here, no child
process) from the start of each batch to its records, loading the decoder and pose encoder included, as each of a
fit's batches pays them; a warm-up batch of one participant and ``min_steps`` steps first takes the one-time imports
out, as a fit's worker has them. The stores that outlive a batch (the pose encoder's features by image,
:data:`rhi.components.vision.pose_encoder.STORE`) are emptied before each model's first batch: its first batch pays for
every picture, the next ones find the pictures the first saw, as a fit's later batches do. A run of fewer than
1500 steps is scaled to 1500 (CPU-s x 1500 / steps).
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from rhi.master import config as configuration
from rhi.master import models
from rhi.master.config.protocol import make_trial
from rhi.master.tasks.illusion.runner import batch_outcomes

TRIAL_STEPS = 1500  # the unit's trial: the protocol's 1500 steps (30 s at 0.02 s)
# Per model: (key, prior, low, high): a few-fold range around each default, as a fit's priors (docs/fit/*.toml).
PRIORS = {
    "paper": (("decoder.visual_variance", "log-uniform", 5.0, 80.0),
              ("brain.proprioceptive_variance", "log-uniform", 0.5, 2.0),
              ("brain.sync_sd", "uniform", 0.05, 0.5), ("brain.gamma0", "log-uniform", 0.003, 0.1)),
    "causal": (("brain.proprioceptive_variance", "log-uniform", 0.5, 2.0),
               ("causal.common_cause_prior", "uniform", 0.1, 0.6),
               ("causal.timing_noise_sd", "log-uniform", 0.03, 0.3),
               ("causal.switching_time", "log-uniform", 5.0, 80.0),
               ("causal.peripersonal_sd", "log-uniform", 0.05, 0.4)),
}


def draw(model: str, rng: np.random.Generator) -> tuple:
    """One participant's values of ``PRIORS[model]``: ((key, value), ...)."""
    values = []
    for key, prior, low, high in PRIORS[model]:
        value = np.exp(rng.uniform(np.log(low), np.log(high))) if prior == "log-uniform" else rng.uniform(low, high)
        values.append((key, float(value)))
    return tuple(values)


def participants(config: dict, count: int, rng: np.random.Generator, model: str) -> list:
    """``count`` participants' trials, every cell of the protocol each, in one list (one lockstep batch)."""
    trials = []
    for _ in range(count):
        own = draw(model, rng)
        mine = configuration.merge(config, {"experiment": {"seed": int(rng.integers(2**62))}})  # its own delays
        trials += [make_trial(mine, "conv", condition, stimulation, 0, own)
                   for condition in config["experiment"]["conditions"]
                   for stimulation in config["experiment"]["stimulations"]]
    return trials


def model_config(model: str, settings, folder: Path) -> tuple[dict, str]:
    """The configuration of ``model``'s fit-like batches and the conv decoder's checkpoint: the trained defaults
    (cached or shipped) when ``fit_trained``, else untrained seeded ones written to ``folder`` (and, for a model
    that sees the pose, an untrained pose encoder of the same preset)."""
    preset_name, resolution = settings.fit_preset
    overrides = {"experiment.resolution": resolution, "experiment.steps": settings.fit_steps,
                 "experiment.decoders": ["conv"], "experiment.trials": 1}
    if settings.fit_trained:
        config = configuration.load(overrides=overrides, model_name=model)
        from rhi.master.decoders.cache import checkpoint_path
        return config, checkpoint_path("conv", config, must_exist=True)
    from rhi.master.bench.sweep_rate import untrained_checkpoint

    checkpoint = untrained_checkpoint("conv", preset_name, resolution, settings.seed, folder)
    key = models.get(model).pose_encoder_key
    if key:
        overrides[key.format(kind="conv")] = untrained_pose_encoder(preset_name, resolution, settings.seed, folder)
    return configuration.load(overrides=overrides, model_name=model), checkpoint


def untrained_pose_encoder(preset_name: str, resolution: int, seed: int, folder: Path) -> str:
    """A pose-encoder file of an untrained encoder (torch seed ``seed``): the speed does not depend on the weights."""
    import torch

    from rhi.components.body import kinematics
    from rhi.components.vision.networks import Encoder, preset
    from rhi.components.vision.pose_encoder import PoseModel, save_encoder
    from rhi.master.decoders.training_data import HALF_RANGES

    torch.manual_seed(seed)
    path = folder / f"pose-untrained-{preset_name}-r{resolution}.pt"
    save_encoder(path, PoseModel(Encoder(preset(preset_name), resolution), kinematics.REST_POSE, HALF_RANGES),
                 preset(preset_name), resolution)
    return str(path)


def model_unit(model: str, settings, folder: Path) -> dict:
    """One model's batches: trials, steps, CPU-s per batch and the unit, CPU-s per 1500-step trial."""
    from rhi.components.vision import pose_encoder

    config, checkpoint = model_config(model, settings, folder)
    rng = np.random.default_rng([settings.seed, settings.fit_models.index(model)])
    warm = configuration.merge(config, {"experiment": {"steps": settings.min_steps}})
    batch_outcomes(warm, "conv", participants(warm, 1, rng, model), checkpoint)
    pose_encoder.STORE.clear()
    cpu, trials, failed = [], 0, 0
    for _ in range(settings.fit_batches):
        batch = participants(config, settings.fit_participants, rng, model)
        began = time.process_time()
        records = batch_outcomes(config, "conv", batch, checkpoint)
        cpu.append(time.process_time() - began)
        trials += len(batch)
        failed += sum(record["status"] != "ok" for record in records)
    return {"trials": trials, "failed": failed, "steps": settings.fit_steps, "batch_cpu_s": cpu,
            "cpu_s": sum(cpu), "cpu_s_per_1500_step_trial": sum(cpu) / trials * TRIAL_STEPS / settings.fit_steps}


def fit_unit(settings) -> dict:
    """The fit-like batches of ``settings.fit_models`` (a baseline, then the model compared with it) and the
    ratio of their units, measured in this run.

    Returns
    -------
    dict
        ``preset``, ``resolution``, ``weights``, ``participants_per_batch``, ``cells``, ``batches``, ``models``
        (per model: :func:`model_unit`'s dict) and ``<compared>_vs_<baseline>`` (``causal_vs_paper``).
    """
    preset_name, resolution = settings.fit_preset
    baseline, compared = settings.fit_models
    with tempfile.TemporaryDirectory(prefix="rhi_bench_fit_") as name:
        rows = {model: model_unit(model, settings, Path(name)) for model in settings.fit_models}
    cells = rows[baseline]["trials"] // (settings.fit_participants * settings.fit_batches)
    return {"preset": preset_name, "resolution": resolution,
            "weights": "trained (cached or shipped)" if settings.fit_trained else f"untrained, torch seed {settings.seed}",
            "participants_per_batch": settings.fit_participants, "cells": cells, "batches": settings.fit_batches,
            "models": rows,
            f"{compared}_vs_{baseline}": (rows[compared]["cpu_s_per_1500_step_trial"]
                                          / rows[baseline]["cpu_s_per_1500_step_trial"])}
