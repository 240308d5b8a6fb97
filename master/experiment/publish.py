"""The experiment into a folder: train what is missing, run the protocol, write every result file.

DIR is written in a staging folder beside it and renamed into place when complete
(:mod:`master.outputs.files`), so it holds either a whole run or nothing from this one.
"""
from __future__ import annotations

import json
import shutil
import time

import numpy as np

from master.experiment import runner as experiment
from master.experiment.decoders import ensure_checkpoints, jacobian_pair
from master.experiment.measures import end_of_trial
from master.experiment.protocol import rubber_pose
from master.outputs import figures, tables
from master.outputs.animation import frames, gif_bytes
from master.outputs.files import atomic_write, package_versions, publish, staging_folder


def body_factory(path):
    """A callable making the body component (None: the native plant) and the body's parameter names."""
    if path is None:
        return None, None
    from components.fmu_adapter import FMUComponent

    probe = FMUComponent(path, name="body")  # checks the body contract now, listing every problem, before any work
    return (lambda: FMUComponent(path, name="body")), set(probe.variables)


def run_into(out, config: dict, body: str | None = None, force: bool = False, progress: bool = False) -> dict:
    """Run the protocol of ``config`` and write DIR = ``out``; returns {failed trial: error}.

    body: an FMU to use as the body (None: the native pymunk plant).
    """
    started = time.perf_counter()
    make_body, declared = body_factory(body)
    staging = staging_folder(out, force)
    try:
        checkpoints, training_seconds = ensure_checkpoints(config, progress=progress)
        trials, times, per_step, run_seconds, failures = experiment.run(config, checkpoints, make_body,
                                                                        progress=progress)
        final = end_of_trial(times, per_step)
        atomic_write(staging / "summary.csv", tables.csv_text(tables.SUMMARY_COLUMNS, tables.summary(trials, final)))
        atomic_write(staging / "trials.csv", tables.trials_csv(trials, times, per_step))
        jacobians = {kind: jacobian_pair(kind, checkpoints[kind], config) for kind in checkpoints}
        written = figures.write_all(staging / "figures", trials, times, per_step, jacobians)
        shown = next((i for i, t in enumerate(trials) if (t.condition, t.stimulation) == ("left", "sync")), 0)
        balls = np.stack([per_step["ball_x_m"][:, shown], per_step["ball_y_m"][:, shown]], axis=1)
        mu = np.stack([per_step["mu_shoulder_deg"][:, shown], per_step["mu_elbow_deg"][:, shown]], axis=1)
        name = f"trial_{trials[shown].decoder}_{trials[shown].condition}_{trials[shown].stimulation}.gif"
        atomic_write(staging / "figures" / name, gif_bytes(frames(mu, rubber_pose(trials[shown].offset_x), balls,
                                                                  config["experiment"]["resolution"])))
        provenance = {
            "command": "rhi experiment", "configuration": config, "body": body or "native pymunk plant",
            "body_keys_not_declared": sorted(f"body.{key}" for key in config["body"]
                                             if declared is not None and key not in declared),
            "checkpoints": checkpoints, "seeds": {"master": config["experiment"]["seed"],
                                                  "trials": [t.__dict__ for t in trials]},
            "versions": package_versions(),
            "timings_s": {"training": training_seconds, "trials": run_seconds,
                          "total": time.perf_counter() - started},
            "figures": written + [name],
            "failed_trials": [{**trial.__dict__, "error": error} for trial, error in failures.items()],
        }
        atomic_write(staging / "run.json", json.dumps(provenance, indent=2, default=str) + "\n")
        publish(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return failures
