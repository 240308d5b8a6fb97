"""``rhi bench --cohort``: CPU-µs per participant-step of every registered model at cohort batch sizes, each part's
share, on the batched arm and on the pymunk arm; a study's cost against its participants' trials
(:mod:`rhi.master.bench.study_cost`); the machine.

A participant-step is one simulated participant advanced one communication step (20 ms), everything included.
Each measurement runs one cell of the protocol (the conv decoder's slot, the left offset, synchronous stroking),
``batch`` participants in one lockstep batch, as a cohort's cell runs, for ``steps`` steps, with the shipped
decoders and pose encoders (64 px) and one torch thread (a cohort's worker is one core). The CPU time
(``time.process_time``: every thread of the process) of each component's steps is summed, the rest of the
stepping is the master's; the set-up (building the system, loading networks, the first images) is left out.
Each cell runs twice: first with the pose encoder's store of features emptied (``first_batch_us``: a cell's first
batch, which pays for every picture), then again (``us_per_participant_step``, and the shares: every later batch
of a study, whose pictures were seen before). The decoder runs in the mode the configuration names
(``decoder.fast``), unchecked.
"""
from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager

import torch

from rhi.components.body.batched import BatchedArm
from rhi.components.component import Component
from rhi.master import config as configuration
from rhi.master import models
from rhi.master.config.protocol import make_trial

BATCHES = (60, 300, 1200)  # participants in one lockstep batch: a cell of a small study, of a fit's batch, of a big one
QUICK_BATCHES = (4, 12)
STEPS, QUICK_STEPS = 100, 4  # measured steps: two stroke periods of 2 s
CELL = ("conv", "left", "sync")  # decoder slot, condition, stimulation
BODIES = {"batched": BatchedArm, "pymunk": None}  # None: the task's default, the pymunk arm


@contextmanager
def cpu_per_component():
    """While open, every component's ``do_step`` adds its CPU seconds to the yielded dict (by component name);
    ``spent["first"]`` is the process's CPU time when the first step began."""
    spent = defaultdict(float)
    original = Component.do_step

    def timed(self, t, h):
        began = time.process_time()
        spent.setdefault("first", began)
        try:
            return original(self, t, h)
        finally:
            spent[self.name] += time.process_time() - began
    Component.do_step = timed
    try:
        yield spent
    finally:
        Component.do_step = original


def measure(model: str, batch: int, body: str, steps: int) -> dict:
    """One cell of ``batch`` participants of ``model`` for ``steps`` steps on ``body`` (a key of :data:`BODIES`).

    Returns
    -------
    dict
        ``model``, ``batch``, ``body``, ``steps``, ``us_per_participant_step`` (CPU) and ``shares`` (each
        component's and the master's fraction of the stepping's CPU time).
    """
    from rhi.components.vision import pose_encoder
    from rhi.master.decoders.cache import decoder_component, ensure_checkpoints
    from rhi.master.tasks.illusion.wiring import run_batch

    config = configuration.load(model_name=model, overrides={"experiment.steps": steps,
                                                             "experiment.decoders": [CELL[0]]})
    checkpoints, _ = ensure_checkpoints(config, progress=False)
    trials = [make_trial(config, *CELL, index) for index in range(batch)]
    torch.set_num_threads(1)
    pose_encoder.STORE.clear()
    maker, runs = BODIES[body], []
    for _ in ("first", "later"):
        decoder = decoder_component(CELL[0], checkpoints[CELL[0]], config, config["decoder"]["fast"], 1)
        with cpu_per_component() as spent:
            run_batch(decoder, trials, config, maker() if maker else None)
            ended = time.process_time()
        stepping = ended - spent.pop("first")
        runs.append((stepping, {**spent, "master": stepping - sum(spent.values())}))
    (first, _), (stepping, parts) = runs
    return {"model": model, "batch": batch, "body": body, "steps": steps,
            "us_per_participant_step": stepping / (batch * steps) * 1e6,
            "first_batch_us": first / (batch * steps) * 1e6,
            "shares": {name: seconds / stepping for name, seconds in sorted(parts.items(), key=lambda kv: -kv[1])}}


def cohort_report(quick: bool = False, model_names=None) -> dict:
    """:func:`measure` for every registered model (or ``model_names``), batch size and body; the study rows
    (:func:`rhi.master.bench.study_cost.study_rows`); the machine (its CPU, and the load before and after)."""
    import os

    from rhi.components.vision.component import available_cores
    from rhi.master.bench.study_cost import study_rows
    from rhi.master.outputs.provenance import cpu_description

    load = os.getloadavg()[0]
    batches, steps = (QUICK_BATCHES, QUICK_STEPS) if quick else (BATCHES, STEPS)
    rows = [measure(model, batch, body, steps) for model in (model_names or models.names())
            for body in BODIES for batch in batches]
    studies = study_rows(steps, quick)
    return {"cell": "/".join(CELL), "steps": steps, "rows": rows, "studies": studies,
            "machine": {"cpu": cpu_description()["model"], "usable_cores": available_cores(),
                        "load_average_before": load, "load_average_after": os.getloadavg()[0]}}


def cohort_table(report: dict) -> str:
    """The report as text: a row per model, body and batch, the parts' shares in percent."""
    from rhi.master.bench.study_cost import study_table

    machine = report["machine"]
    lines = [f"machine: {machine['cpu']}, {machine['usable_cores']} usable cores; load average "
             f"{machine['load_average_before']:.1f} before, {machine['load_average_after']:.1f} after",
             f"CPU-µs per participant-step, one cell ({report['cell']}), {report['steps']} steps, one thread "
             "(first: the cell's first batch, which draws and encodes every picture)",
             f"{'model':10s} {'body':8s} {'batch':>6s} {'µs':>8s} {'first':>8s}  shares"]
    for row in report["rows"]:
        shares = ", ".join(f"{name} {share:.0%}" for name, share in row["shares"].items())
        lines.append(f"{row['model']:10s} {row['body']:8s} {row['batch']:6d} {row['us_per_participant_step']:8.2f} "
                     f"{row['first_batch_us']:8.2f}  {shares}")
    return "\n".join([*lines, "", study_table(report["studies"])])
