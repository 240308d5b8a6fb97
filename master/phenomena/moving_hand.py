"""`rhi phenomenon moving-hand`: the moving rubber hand, drift and common-cause belief per visuomotor delay.

The real arm (free) swings by itself at the shoulder; the rubber arm, the only arm in view, repeats the
movement after a delay; no touch. The paper's brain perceives (its action is not fed to the body: the movement
is the participant's own, and the released agent's illusion task ran without action); its gamma weighs the
delay between the seen and the felt turning points of the movement by eqs. 8-9
(:mod:`rhi.components.brain.turning_points`). Drift and gamma are the means over the last movement period.
The task's system: :mod:`rhi.master.tasks.moving_hand`.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from rhi.components.body import kinematics
from rhi.master import config as configuration
from rhi.master.config import population
from rhi.master import models
from rhi.master.cosim import ConfigError
from rhi.master.decoders.cache import check_decoders, per_decoder
from rhi.master.outputs import tables
from rhi.master.outputs.files import atomic_write, output_folder
from rhi.master.outputs.provenance import package_versions
from rhi.master.runtime.context import RunContext
from rhi.master.runtime.pool import Workers
from rhi.master.tasks import moving_hand as task

NAME = task.NAME
HUMAN_TABLE = "moving_hand"  # its human references in human.toml
COLUMNS = ["decoder", "delay_s", "drift_cm", "drift_relative", "gamma", "gamma_relative"]


def shipped_file() -> Path:
    """The shipped protocol file, master/phenomena/moving_hand.toml."""
    from importlib import resources
    return Path(str(resources.files("rhi.master.phenomena").joinpath("moving_hand.toml")))


def load(path=None, model_name: str = "paper") -> dict:
    """The defaults, the model, and the protocol's [moving_hand] table (and any other keys of the file) over them."""
    given = configuration.read_toml(path if path is not None else shipped_file())
    protocol = given.pop("moving_hand", None)
    if not isinstance(protocol, dict):
        raise ConfigError(f"{path}: a moving-hand file needs a [moving_hand] table (copy {shipped_file()})")
    shipped = configuration.read_toml(shipped_file())["moving_hand"]
    config = configuration.defaults()
    config.pop("quick")
    config = configuration.with_model(config, model_name)
    config = configuration.merge({**config, "moving_hand": shipped}, {"moving_hand": protocol, **given})
    population.refuse_in(config, "rhi phenomenon moving-hand")
    configuration.validate(config)
    moving = config["moving_hand"]
    step = config["experiment"]["step_size"]
    if not moving["delays"] or any(not 0 <= d or abs(d / step - round(d / step)) > 1e-6 for d in moving["delays"]):
        raise ConfigError(f"moving_hand.delays = {moving['delays']}: each must be >= 0 and a whole number of "
                          f"{step} s steps")
    length = config["experiment"]["steps"] * step
    longest = max(moving["delays"])
    if not longest <= length:  # the seen hand shows the real one d s earlier: over the trial, it never moves in it
        raise ConfigError(f"moving_hand.delays: {longest:g} s is longer than the trial ({length:g} s = "
                          "experiment.steps x step_size), so the seen hand would never move in it")
    if moving["condition"] not in config["conditions"]:
        raise ConfigError(f"moving_hand.condition: unknown condition {moving['condition']!r}")
    for key in ("amplitude", "period"):
        if not moving[key] > 0:
            raise ConfigError(f"moving_hand.{key} must be positive, got {moving[key]}")
    if moving["period"] > config["experiment"]["steps"] * step:
        raise ConfigError("moving_hand.period is longer than the trial (experiment.steps x step_size)")
    return config


def decoder_delays(config: dict, kind: str, path: str) -> dict:
    """Every delay of one decoder in one lockstep batch (a job): drift and gamma per delay."""
    result = task.simulate_delays(config, kind, path)
    return measures(result.times, result.values, config["moving_hand"]["period"])


def measures(times, values, period: float) -> dict:
    """Per trial: the drift (perceived minus real hand x, cm) and gamma, each its mean over the last period
    (rows after the trial's end minus one period). The belief lags the moving arm (it relaxes to s_p at
    1/Sigma_p), so the drift at any one instant swings with the movement; over a whole period the lag's
    swing averages out."""
    mu = values["brain.mu"]
    perceived, _ = kinematics.forward(mu[..., 0], mu[..., 1])
    real, _ = kinematics.forward(values["body.q_shoulder"], values["body.q_elbow"])
    drift = 100.0 * (perceived - real)
    last = np.asarray(times) > times[-1] - period + 1e-9
    return {"drift_cm": drift[last].mean(axis=0), "gamma": values["brain.gamma"][last].mean(axis=0)}


def rows(config: dict, found: dict[str, dict]) -> list[list]:
    """moving_hand.csv's rows (``COLUMNS``): per decoder and delay, the drift and gamma, and each relative to its
    value at 0 s.

    Parameters
    ----------
    config : dict
        The configuration; ``moving_hand.delays`` in s.
    found : dict
        Decoder -> :func:`measures`: ``drift_cm`` (cm) and ``gamma``, each of shape (delays,).

    Returns
    -------
    list of list
        A row per decoder and delay, numbers as text; the relative values NaN without a 0 s delay.
    """
    delays = config["moving_hand"]["delays"]
    out = []
    for kind, values in found.items():
        zero = {key: values[key][delays.index(0.0)] if 0.0 in delays else np.nan for key in ("drift_cm", "gamma")}
        for i, delay in enumerate(delays):
            out.append([kind, tables.number(delay), tables.number(values["drift_cm"][i]),
                        tables.number(values["drift_cm"][i] / zero["drift_cm"]), tables.number(values["gamma"][i]),
                        tables.number(values["gamma"][i] / zero["gamma"])])
    return out


def figure(config: dict, found: dict[str, dict]):
    """moving_hand.png's ``Figure``: drift and gamma relative to 0 s against the delay, a line per decoder, with
    the human references."""
    from rhi.master.outputs.figures import subplots
    from rhi.master.phenomena.report import caption, draw_human, human_references

    delays = config["moving_hand"]["delays"]
    references = human_references(HUMAN_TABLE)
    fig, axes = subplots(1, 2, figsize=(10, 5.4))
    for axis, key, label in ((axes[0], "drift_cm", "drift toward the rubber hand, relative to 0 s"),
                             (axes[1], "gamma", "gamma (common cause), relative to 0 s")):
        for kind, values in found.items():
            zero = values[key][delays.index(0.0)] if 0.0 in delays else 1.0
            axis.plot(delays, values[key] / zero, "o-", label=f"{models.of(config).name} model, {kind}")
        axis.axhline(0.5, color="gray", ls=":", lw=1, label="half the 0 s value")
        axis.set_xlim(-0.05, max(delays) + 0.05)
        draw_human(axis, references, with_labels=axis is axes[0])
        axis.set_xlabel("visuomotor delay (s)")
        axis.set_ylabel(label)
        axis.legend(fontsize="x-small")
    fig.suptitle("rhi phenomenon moving-hand: the rubber arm repeats the real arm's movement after a delay",
                 fontsize=10)
    fig.text(0.01, 0.005, caption(references, models.of(config).name), fontsize=6, va="bottom", wrap=True)
    fig.tight_layout(rect=(0, 0.2, 1, 0.95))  # room for the caption
    return fig


def run_into(out, config: dict, context: RunContext | None = None) -> list[str]:
    """Run the protocol for each decoder (side by side) and write DIR: moving_hand.csv, moving_hand.png, run.json."""
    from rhi.master.outputs.figures import save

    started, force = time.perf_counter(), (context or RunContext()).force
    check_decoders(config)
    with output_folder(out, force) as staging, Workers() as workers:
        checkpoints, found = per_decoder(config, decoder_delays, workers)
        atomic_write(staging / "moving_hand.csv", tables.csv_text(COLUMNS, rows(config, found)))
        save(figure(config, found), staging / "moving_hand.png")
        atomic_write(staging / "run.json", json.dumps({
            "schema_version": tables.SCHEMA_VERSION, "command": f"rhi phenomenon {NAME}",
            "model": models.of(config).name,
            "configuration": config, "checkpoints": checkpoints, "versions": package_versions(),
            "timings_s": {"total": time.perf_counter() - started}}, indent=2, default=str) + "\n")
    return ["moving_hand.csv", "moving_hand.png", "run.json"]

