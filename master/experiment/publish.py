"""The experiment into a folder: train what is missing, run the protocol, write every result file.

DIR is written in a staging folder beside it and renamed into place when complete
(:mod:`master.outputs.files`), so it holds either a whole run or nothing from this one.
"""
from __future__ import annotations

import json
import time

import numpy as np

from master.experiment import runner as experiment
from master.experiment.runner import body_factory
from master.experiment.decoders import check_decoders, ensure_checkpoints, jacobian_pair
from master.experiment.fast_check import verdicts
from master.experiment.parallel import Workers, call
from master.experiment.measures import end_of_trial
from master.experiment.protocol import plan, rubber_pose
from master.outputs import figures, tables
from master.outputs.files import atomic_write, check_output, output_folder
from master.outputs.provenance import package_versions
from master.outputs.animation import frames, gif_bytes


def run_into(out, config: dict, body: str | None = None, force: bool = False, progress: bool = False,
             device: str = "cpu") -> dict:
    """Run the protocol of ``config`` and write DIR = ``out``; returns {failed trial: error}.

    body: an FMU to use as the body (None: the native pymunk plant). device: where the decoders train and run
    (cpu, cuda; resolved). Everything that can be checked is
    checked before the staging folder exists and before any training: the output folder, the decoders'
    checkpoints (kind, resolution, camera) or training settings, the body FMU.
    """
    started = time.perf_counter()
    check_output(out, force)
    check_decoders(config, device)
    declared = body_factory(body, config)[1]
    with output_folder(out, force) as staging, Workers(1 if device != "cpu" else None) as workers:
        checkpoints, training_seconds = ensure_checkpoints(config, progress=progress, device=device, workers=workers)
        began = time.perf_counter()
        modes = verdicts(config, checkpoints, workers, progress)
        check_seconds = time.perf_counter() - began
        trials, times, per_step, run_seconds, failures = experiment.run(
            config, checkpoints, body, progress=progress, fast={kind: mode["fast"] for kind, mode in modes.items()},
            device=device, workers=workers)
        final = end_of_trial(times, per_step)
        summary = tables.summary(trials, final, planned=tables.cells(plan(config)))
        atomic_write(staging / "summary.csv", tables.csv_text(tables.SUMMARY_COLUMNS, summary))
        (staging / "figures").mkdir()
        shown = next((i for i, t in enumerate(trials) if (t.condition, t.stimulation) == ("left", "sync")), 0)
        name = f"trial_{trials[shown].decoder}_{trials[shown].condition}_{trials[shown].stimulation}.gif"
        animated = {key: per_step[key][:, shown] for key in ANIMATED}
        workers.map(call, [  # the files, side by side on the workers the run started (else here), the longest first
            (write_trials, staging / "trials.csv", trials, times, per_step),
            (write_jacobians, staging / "figures" / "h_jacobians.png", checkpoints, config),
            (write_animation, staging / "figures" / name, trials[shown], animated, config["experiment"]["resolution"]),
            *figures.panel_jobs(staging / "figures", trials, times, per_step, final, None)], start=False)
        provenance = {
            "schema_version": tables.SCHEMA_VERSION,
            "command": "rhi experiment", "model": config.get("model", {}).get("name", "paper"),
            "configuration": config, "body": body or "native pymunk plant",
            "body_keys_not_declared": sorted(f"body.{key}" for key in config["body"]
                                             if declared is not None and key not in declared),
            "checkpoints": checkpoints, "fast_mode": modes, "device": device,
            "seeds": {"master": config["experiment"]["seed"], "trials": [t.__dict__ for t in trials]},
            "versions": package_versions(),
            "timings_s": {"training": training_seconds, "fast_check": check_seconds, "trials": run_seconds,
                          "total": time.perf_counter() - started},
            "figures": sorted(path.name for path in (staging / "figures").iterdir()),
            "failed_trials": [{**trial.__dict__, "error": error} for trial, error in failures.items()],
        }
        atomic_write(staging / "run.json", json.dumps(provenance, indent=2, default=str) + "\n")
    return failures


ANIMATED = ("ball_x_m", "ball_y_m", "mu_shoulder_deg", "mu_elbow_deg")  # the measures the animation shows


def write_trials(path, trials, times, per_step) -> None:
    """trials.csv (a job of :func:`run_into`)."""
    atomic_write(path, tables.trials_csv(trials, times, per_step))


def write_jacobians(path, checkpoints: dict[str, str], config: dict) -> None:
    """Panel h, each decoder's Jacobian images at rest (a job of :func:`run_into`)."""
    figures.jacobian_images({kind: jacobian_pair(kind, checkpoints[kind], config) for kind in checkpoints}, path)


def write_animation(path, trial, measures: dict[str, np.ndarray], resolution: int) -> None:
    """The animation of one trial, from its ``measures[key]`` per step (a job of :func:`run_into`)."""
    balls = np.stack([measures["ball_x_m"], measures["ball_y_m"]], axis=1)
    mu = np.stack([measures["mu_shoulder_deg"], measures["mu_elbow_deg"]], axis=1)
    atomic_write(path, gif_bytes(frames(mu, rubber_pose(trial.offset_x), balls, resolution)))
