"""`rhi reach` into a folder: every decoder's reaches in lockstep, then summary.csv, goals.csv, trials.csv,
figures/ and run.json, whole or not at all (docs/reach.md)."""
from __future__ import annotations

import json
import time

import numpy as np

from rhi.master import models
from rhi.master.cosim import SimulationError
from rhi.master.tasks.reach import task as reach
from rhi.master.decoders.cache import check_decoders, ensure_checkpoints
from rhi.master.decoders.cache import pose_encoder_path
from rhi.master.runtime.context import RunContext
from rhi.master.runtime.pool import JOB_THREADS, Workers, run_jobs
from rhi.master.tasks.illusion.runner import bar_positions, step_bar, without_failures
from rhi.master.outputs import tables
from rhi.master.outputs.files import atomic_write, check_output, output_folder
from rhi.master.outputs.provenance import package_versions

# The released agent's reaching logs (thomasroodnl/active-inference-rhi, active-inference-agent/model_operation/
# operation_logs/reach_results, 40 runs per file set): the runs whose last logged cartesian_distance is under
# 1 cm, and those whose last distance exceeds their first. "s2nr2u" is its ConvDecoder, "vae" its VAE.
RELEASED_AGENT = {("conv", "near"): (40, 0), ("conv", "far"): (12, 12), ("vae", "near"): (40, 0),
                  ("vae", "far"): (11, 12)}
RELEASED_AGENT_GOALS = 40

SUMMARY_COLUMNS = ["decoder", "band", "n_goals", "n_reached", "reached_fraction", "radius_cm",
                   "start_distance_cm_mean", "final_distance_cm_mean", "final_distance_cm_sd",
                   "final_distance_cm_median", "time_to_reach_s_mean", "path_length_cm_mean",
                   "n_farther_than_start", "released_agent_reached", "released_agent_farther", "released_agent_goals"]
GOAL_COLUMNS = ["decoder", "band", "goal", "seed", "goal_shoulder_offset_deg", "goal_elbow_offset_deg",
                "start_distance_cm", "final_distance_cm", "reached", "time_to_reach_s", "path_length_cm",
                "farther_than_start", "final_belief_distance_cm"]
STEP_KEYS = ["hand_x_m", "hand_y_m", "distance_cm", "belief_distance_cm", "mu_shoulder_deg", "mu_elbow_deg",
             "s_p_shoulder_deg", "s_p_elbow_deg", "action_shoulder_deg_s", "action_elbow_deg_s", "gamma"]


def decoder_reaches(config: dict, kind: str, path: str, trials: list, position: int | None = None):
    """One decoder's reaches in one lockstep batch (a job): (kept trials, times, per-step measures, seconds,
    {failed trial: error})."""
    def run_trials(batch):
        with step_bar(f"{kind} reaches x{len(batch)}", config["experiment"]["steps"], position) as update:
            return reach.run_reaches(kind, path, batch, config, JOB_THREADS, update)

    began = time.perf_counter()
    try:
        result, kept, failed = without_failures(run_trials, trials)
    except SimulationError as error:
        failed, result, kept = {**error.failures, **{t: str(error) for t in trials}}, None, []
    if result is None:
        return kept, None, None, time.perf_counter() - began, failed
    return kept, result.times, reach.measures(result), time.perf_counter() - began, failed


def summary_rows(trials, final: dict[str, np.ndarray], radius_cm: float) -> list[list]:
    """One row per decoder x band (:data:`SUMMARY_COLUMNS`)."""
    rows = []
    for (decoder, band), members in tables.cells(trials, key=lambda t: (t.decoder, t.band)).items():
        pick = {key: np.asarray(values)[members] for key, values in final.items()}
        reached = pick["reached"].astype(bool)
        released, farther = RELEASED_AGENT.get((decoder, band), (None, None))
        mean = lambda values: tables.number(np.mean(values)) if len(values) else ""  # noqa: E731
        sd = tables.mean_sd(pick["final_distance_cm"])[1]
        rows.append([decoder, band, len(members), int(reached.sum()), tables.number(reached.mean()),
                     tables.number(radius_cm), mean(pick["start_distance_cm"]), mean(pick["final_distance_cm"]),
                     tables.number(sd), tables.number(np.median(pick["final_distance_cm"])),
                     mean(pick["time_to_reach_s"][reached]), mean(pick["path_length_cm"]),
                     int(pick["farther_than_start"].sum()), "" if released is None else released,
                     "" if farther is None else farther, "" if released is None else RELEASED_AGENT_GOALS])
    return rows


def goal_rows(trials, final: dict[str, np.ndarray]) -> list[list]:
    """One row per reach (:data:`GOAL_COLUMNS`)."""
    def cell(value):
        return int(value) if isinstance(value, (bool, np.bool_)) else tables.number(value)
    return [[t.decoder, t.band, t.index, t.seed, tables.number(t.shoulder_offset), tables.number(t.elbow_offset),
             *(cell(final[key][i]) for key in GOAL_COLUMNS[6:])] for i, t in enumerate(trials)]


def trials_text(trials, times, per_step: dict[str, np.ndarray], every: int) -> str:
    """trials.csv: one row per reach x recorded step (every ``every`` steps, and the last)."""
    steps = sorted(set(range(0, len(times), every)) | {len(times) - 1})
    rows = [[t.decoder, t.band, t.index, tables.number(times[s]), *(tables.number(per_step[key][s, i])
                                                                     for key in STEP_KEYS)]
            for i, t in enumerate(trials) for s in steps]
    return tables.csv_text(["decoder", "band", "goal", "time_s", *STEP_KEYS], rows)


def run_into(out, config: dict, context: RunContext | None = None) -> dict:
    """Run every reach of ``config`` and write DIR = ``out`` (context: force, progress); returns {failed trial:
    error}."""
    from rhi.master.tasks.reach.figures import write_figures

    started, context = time.perf_counter(), context or RunContext()
    force, progress = context.force, context.progress
    check_output(out, force)
    check_decoders(config)
    trials = reach.plan(config)
    for kind in config["experiment"]["decoders"]:  # the encoders and the wiring, before any work
        if reach.attractor(config) == "body" or models.of(config).sees_pose:
            pose_encoder_path(kind, config)
    with output_folder(out, force) as staging, Workers() as workers:
        checkpoints, training_seconds = ensure_checkpoints(config, progress=progress, workers=workers)
        kinds = config["experiment"]["decoders"]
        jobs = [(config, kind, checkpoints[kind], [t for t in trials if t.decoder == kind], position)
                for kind, position in zip(kinds, bar_positions(len(kinds), progress, None, workers))]
        kept, blocks, seconds, failures, times = [], [], {}, {}, None
        for kind, (batch, batch_times, per_step, spent, failed) in zip(kinds, run_jobs(decoder_reaches, jobs,
                                                                                        workers=workers)):
            seconds[kind] = spent
            failures.update(failed)
            if per_step is not None:
                kept += batch
                blocks.append(per_step)
                times = batch_times
        if not blocks:
            raise SimulationError("reach", 0.0, "every reach failed: " + "; ".join(sorted(set(failures.values()))))
        per_step = {key: np.concatenate([block[key] for block in blocks], axis=1) for key in blocks[0]}
        radius = config["reach"]["radius_cm"]
        final = reach.outcomes(times, per_step, radius)
        atomic_write(staging / "summary.csv", tables.csv_text(SUMMARY_COLUMNS, summary_rows(kept, final, radius)))
        atomic_write(staging / "goals.csv", tables.csv_text(GOAL_COLUMNS, goal_rows(kept, final)))
        atomic_write(staging / "trials.csv", trials_text(kept, times, per_step, config["reach"]["record_every"]))
        (staging / "figures").mkdir()
        write_figures(staging / "figures", kept, times, per_step, final, radius)
        provenance = {
            "schema_version": tables.SCHEMA_VERSION, "command": "rhi reach",
            "model": models.of(config).name, "attractor": reach.attractor(config),
            "configuration": config, "checkpoints": checkpoints,
            "seeds": {"master": config["experiment"]["seed"], "goals": [t.__dict__ for t in kept]},
            "released_agent": {f"{d}/{b}": {"reached": r, "farther_than_start": f, "goals": RELEASED_AGENT_GOALS}
                               for (d, b), (r, f) in RELEASED_AGENT.items()},
            "versions": package_versions(),
            "timings_s": {"training": training_seconds, "reaches": seconds, "total": time.perf_counter() - started},
            "figures": sorted(path.name for path in (staging / "figures").iterdir()),
            "failed_trials": [{**trial.__dict__, "error": error} for trial, error in failures.items()],
        }
        atomic_write(staging / "run.json", json.dumps(provenance, indent=2, default=str) + "\n")
    return failures
