"""`rhi phenomenon reach-after`: reaching after the illusion, the endpoint's bias against the drift.

The experiment's trial (the held arm, the rubber arm in view, synchronous or asynchronous touch) runs to
``release``; then the touches stop, the load cell lets the hand go (``body.release_time``), and a target appears:
the camera's image of the arm at the target pose, the `rhi reach` attractor (docs/reach.md), through a
:class:`~rhi.components.brain.goal.GoalOnset`. The action law is the reach's (the released agent's integrator).
Measured: the drift at release, and the hand's x error from the target ``window`` seconds after release,
signed toward the rubber hand.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from rhi.components.body import kinematics
from rhi.components.component import ComponentError
from rhi.master import config as configuration
from rhi.master import models
from rhi.master.cosim import ConfigError
from rhi.master.decoders.cache import check_decoders, per_decoder
from rhi.master.outputs import tables
from rhi.master.outputs.files import atomic_write, output_folder
from rhi.master.outputs.provenance import package_versions
from rhi.master.runtime.context import RunContext
from rhi.master.runtime.pool import Workers
from rhi.master.tasks import reach_after as task

NAME = task.NAME
COLUMNS = ["decoder", "condition", "stimulation", "n_trials", "drift_at_release_cm_mean", "endpoint_bias_cm_mean",
           "endpoint_bias_cm_sd", "endpoint_error_cm_mean", "gamma_at_release_mean"]


def shipped_file() -> Path:
    """The shipped protocol file, master/phenomena/reach_after.toml."""
    from importlib import resources
    return Path(str(resources.files("rhi.master.phenomena").joinpath("reach_after.toml")))


def load(path=None, model_name: str = "paper") -> dict:
    """The defaults, the model, the file's [reach_after] table and its other keys over them (the shipped file's
    first)."""
    config = configuration.defaults()
    config.pop("quick")
    config = configuration.with_model(config, model_name)
    shipped = configuration.read_toml(shipped_file())
    config = configuration.merge({**config, "reach_after": shipped.pop("reach_after")}, shipped)
    if path is not None:
        config = configuration.merge(config, configuration.read_toml(path))
    configuration.validate(config)
    after, step = config["reach_after"], config["experiment"]["step_size"]
    for key in ("release", "window", "precision_ratio"):
        if not after[key] > 0:
            raise ConfigError(f"reach_after.{key} must be positive, got {after[key]}")
    from rhi.master.tasks.reach.task import check_goal_variance

    check_goal_variance(config, "reach_after.precision_ratio", after["precision_ratio"])
    if len(after["target"]) != 2:
        raise ConfigError(f"reach_after.target = {after['target']} must be [dx, dy] in m from the resting hand")
    try:
        kinematics.inverse(kinematics.REST_HAND[0] + after["target"][0], kinematics.REST_HAND[1] + after["target"][1])
    except ComponentError as error:
        raise ConfigError(f"reach_after.target = {after['target']}: {error}") from None
    config["experiment"]["steps"] = steps = int(round((after["release"] + after["window"]) / step))
    config["stimulus"]["stop_time"] = after["release"]
    config["body"]["release_time"] = after["release"]
    needed, what = configuration.memory_needed(config)  # the steps the release and the window set, before any work
    available = configuration.physical_memory()
    if available and needed > available:
        raise ConfigError(f"reach_after.release + reach_after.window = {after['release'] + after['window']:g} s is "
                          f"{steps} steps of {step:g} s: this run would need about {configuration.size(needed)} of "
                          f"memory ({what}), more than this machine's {configuration.size(available)}; lower "
                          "reach_after.release or reach_after.window")
    configuration.validate(config)  # again, with the steps, the touches' end and the release they set
    return config


def decoder_trials(config: dict, kind: str, path: str):
    """One decoder's trials in one lockstep batch (a job): the trials and their per-trial values of the table."""
    trials, result = task.simulate_trials(config, kind, path)
    return trials, measures(result.times, result.values, config, trials)


def measures(times, values, config: dict, trials) -> dict:
    """Per trial: the drift and gamma at release; the hand's error from the target at the end (cm), and its x
    part signed toward the rubber hand (positive: toward it)."""
    release = int(np.argmin(np.abs(np.asarray(times) - config["reach_after"]["release"])))
    mu = values["brain.mu"]
    perceived, _ = kinematics.forward(mu[..., 0], mu[..., 1])
    real, _ = kinematics.forward(values["body.q_shoulder"], values["body.q_elbow"])
    target = np.array(kinematics.forward(*task.target_pose(config)))
    error_x = 100.0 * (values["body.hand_x"][-1] - target[0])
    error = 100.0 * np.hypot(values["body.hand_x"][-1] - target[0], values["body.hand_y"][-1] - target[1])
    toward = np.sign([t.offset_x for t in trials])
    return {"drift_at_release_cm": 100.0 * (perceived[release] - real[release]) * np.where(toward == 0, 1, toward),
            "endpoint_bias_cm": error_x * np.where(toward == 0, 1, toward), "endpoint_error_cm": error,
            "gamma_at_release": values["brain.gamma"][release]}


def rows(found: list[tuple]) -> list[list]:
    """reach_after.csv's rows (``COLUMNS``): per decoder x condition x stimulation, the number of trials, the means
    of the per-trial values and the endpoint bias's sd.

    Parameters
    ----------
    found : list of tuple
        Per decoder, (its trials, :func:`measures` of them): drift and endpoint values in cm, each of shape
        (trials,).

    Returns
    -------
    list of list
        A row per cell, numbers as text.
    """
    out = []
    for trials, values in found:
        for (decoder, condition, stimulation), members in tables.cells(trials).items():
            pick = {key: np.asarray(v)[members] for key, v in values.items()}
            mean, sd = tables.mean_sd(pick["endpoint_bias_cm"])
            out.append([decoder, condition, stimulation, len(members),
                        tables.number(pick["drift_at_release_cm"].mean()), tables.number(mean), tables.number(sd),
                        tables.number(pick["endpoint_error_cm"].mean()), tables.number(pick["gamma_at_release"].mean())])
    return out


def run_into(out, config: dict, context: RunContext | None = None) -> list[str]:
    """Every decoder's trials side by side; DIR: reach_after.csv, run.json."""
    started, force = time.perf_counter(), (context or RunContext()).force
    check_decoders(config)
    with output_folder(out, force) as staging, Workers() as workers:
        checkpoints, by_kind = per_decoder(config, decoder_trials, workers)
        found = list(by_kind.values())
        atomic_write(staging / "reach_after.csv", tables.csv_text(COLUMNS, rows(found)))
        atomic_write(staging / "run.json", json.dumps({
            "schema_version": tables.SCHEMA_VERSION, "command": f"rhi phenomenon {NAME}",
            "model": models.of(config).name,
            "configuration": config, "checkpoints": checkpoints, "versions": package_versions(),
            "seeds": [t.__dict__ for trials, _ in found for t in trials],
            "timings_s": {"total": time.perf_counter() - started}}, indent=2, default=str) + "\n")
    return ["reach_after.csv", "run.json"]
