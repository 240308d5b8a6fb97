"""``rhi bench --cohort``'s study rows: the CPU of one study of n participants against n participants' trials as
clones, in a lockstep batch of the same size.

A study is the model's protocol for one decoder (its conditions x stimulations, the conv slot) with ``n`` participants
drawn from a population (:func:`population_of`), all its n x cells trials in one lockstep batch on the batched arm,
as ``rhi power`` and a group fit run a study: drawing the participants and making the trials (``plan``), then
stepping them. The reference is the same protocol with n clones (no population) in a batch of the same size; its
CPU per trial is "one trial in the same batch size". The ratio is the study's CPU over n x cells such trials':
the bound, 1.2, says a study costs about its participants' trials, not more.

Both batches start with the pose encoder's store of features emptied (each pays for its first pictures) and with
their networks already loaded; the CPU is ``time.process_time`` (every thread of the process), one torch thread,
the least of REPEATS runs of each.
"""
from __future__ import annotations

import time

import torch

from rhi.master import config as configuration
from rhi.master import models
from rhi.master.config.protocol import plan

STUDY_SIZES, QUICK_STUDY_SIZES = (10, 20, 40), (2, 3)
REPEATS = 3  # each batch measured this many times, alternating, its least CPU kept
BOUND = 1.2  # a study of n within 1.2 x its n participants' trials as clones (docs/performance.md)

# docs/population/paper.toml's population (free spreads, illustrative: docs/population.md, "Shipped populations")
PAPER_POPULATION = {"brain.gamma0": {"distribution": "logit-normal", "logit_sd": 1.0, "high": 0.5},
                    "decoder.visual_variance": {"distribution": "log-normal", "log_sd": 0.5},
                    "brain.proprioceptive_variance": {"distribution": "log-normal", "log_sd": 0.5, "low": 0.1}}
SPREAD = {"log-uniform": ("log-normal", "log_sd", 0.5), "uniform": ("logit-normal", "logit_sd", 1.0)}


def free_parameter_population() -> dict:
    """The ownership model's bench population: a log-normal (log-sd 0.5) over each log-uniform free parameter
    (``FREE_PARAMETERS``) and a logit-normal (logit-sd 1) over each uniform one, centred on the configured value
    and bounded by the prior's range (free, illustrative spreads: the cost, not the cohort, is measured)."""
    from rhi.master.models.ownership import FREE_PARAMETERS

    table = {}
    for key, (prior, low, high) in FREE_PARAMETERS.items():
        distribution, field, spread = SPREAD[prior]
        table[key] = {"distribution": distribution, field: spread, "low": low, "high": high}
    return table


# The models whose studies the bench times, each with the population its participants are drawn from
STUDY_POPULATIONS = {"paper": lambda: PAPER_POPULATION, "ownership": free_parameter_population}


def population_of(model: str) -> dict:
    """The bench's population of ``model`` (one of :data:`STUDY_POPULATIONS`)."""
    return STUDY_POPULATIONS[model]()


def batch_cpu(config: dict, checkpoint: str, with_population: bool) -> tuple[float, int, int | None]:
    """CPU seconds of planning and stepping ``config``'s protocol in one lockstep batch on the batched arm, its
    trials, and the linearisations its fast decoder evaluated (None: the model reads no pixel term, or the decoder
    runs exact); the decoder is built before the clock starts."""
    from rhi.components.body.batched import BatchedArm
    from rhi.components.vision import pose_encoder
    from rhi.master.decoders.cache import decoder_component
    from rhi.master.tasks.illusion.wiring import run_batch

    decoder = decoder_component("conv", checkpoint, config, config["decoder"]["fast"], 1)
    body = BatchedArm()
    pose_encoder.STORE.clear()
    began = time.process_time()
    trials = plan(config)
    assert with_population == any(t.overrides for t in trials)
    run_batch(decoder, trials, config, body)
    spent = time.process_time() - began
    used = getattr(decoder, "decoder_points", None) if models.of(config).reads_pixels(config) else None
    return spent, len(trials), used


def study_cost(model: str, n: int, steps: int, exact: bool = False) -> dict:
    """One study of ``n`` participants of ``model`` against n x cells clone trials in a batch of the same size.
    exact: the decoder without its fast mode (``decoder.fast = false``): every trial evaluates the decoder at its own
    belief each step, so that no two trials share work and the ratio is the population's own cost.

    Returns
    -------
    dict
        ``model``, ``participants``, ``cells``, ``batch`` (trials in each batch), ``steps``, ``study_cpu_s``,
        ``trial_cpu_s`` (a clone trial's CPU in the batch of the same size), ``ratio`` (the study's CPU over
        n x cells clone trials'), ``exact``, and the linearisations the fast decoder evaluated in each batch
        (``study_decoder_points``, ``clone_decoder_points``; None where none runs): clones of a cell walk one path
        and share them, distinct participants each walk their own.
    """
    from rhi.master.decoders.cache import ensure_checkpoints

    overrides = {"experiment.steps": steps, "experiment.decoders": ["conv"], "experiment.trials": n}
    if exact:
        overrides["decoder.fast"] = False
    clones = configuration.load(model_name=model, overrides=overrides)
    study = configuration.merge(clones, {"population": population_of(model)})
    configuration.validate(study)
    checkpoint = ensure_checkpoints(clones, progress=False)[0]["conv"]
    torch.set_num_threads(1)
    batch_cpu(clones, checkpoint, False)  # warm: the networks, the C body, numpy's first calls
    runs = [(batch_cpu(study, checkpoint, True), batch_cpu(clones, checkpoint, False)) for _ in range(REPEATS)]
    (_, trials, study_points), (_, same, clone_points) = runs[0]
    assert same == trials
    # the least CPU of each over the repeats: the run least disturbed by other work on the machine
    study_s, clone_s = (min(run[side][0] for run in runs) for side in (0, 1))
    return {"model": model, "exact": exact, "participants": n, "cells": trials // n, "batch": trials, "steps": steps,
            "study_cpu_s": study_s, "trial_cpu_s": clone_s / trials, "ratio": study_s / clone_s,
            "study_decoder_points": study_points, "clone_decoder_points": clone_points}


def study_rows(steps: int, quick: bool = False) -> list[dict]:
    """:func:`study_cost` of ``steps`` steps for each model of :data:`STUDY_POPULATIONS` and study size, then the
    paper model's smallest study with the exact decoder (the fast decoder's clones share work that distinct
    participants cannot: that row shows the population's cost without it)."""
    sizes = QUICK_STUDY_SIZES if quick else STUDY_SIZES
    return [*(study_cost(model, n, steps) for model in STUDY_POPULATIONS for n in sizes),
            study_cost("paper", sizes[0], steps, exact=True)]


def study_table(rows: list[dict]) -> str:
    """The study rows as text."""
    lines = [f"a study of n participants (a population, every cell in one lockstep batch, batched arm) against n "
             f"participants' trials as clones in a batch of the same size; CPU-s (bound: ratio <= {BOUND:g})",
             f"{'model':12s} {'n':>4s} {'cells':>5s} {'batch':>6s} {'study s':>9s} {'n x trials s':>12s} {'ratio':>6s}"
             f"  decoder points (study, clones)"]
    for row in rows:
        points = ("-" if row["study_decoder_points"] is None
                  else f"{row['study_decoder_points']}, {row['clone_decoder_points']}")
        model = f"{row['model']} exact" if row.get("exact") else row["model"]
        lines.append(f"{model:12s} {row['participants']:4d} {row['cells']:5d} {row['batch']:6d} "
                     f"{row['study_cpu_s']:9.3f} {row['trial_cpu_s'] * row['batch']:12.3f} {row['ratio']:6.3f}  {points}")
    return "\n".join(lines)
