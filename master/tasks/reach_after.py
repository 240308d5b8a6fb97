"""The reach-after task (``rhi phenomenon reach-after``): the illusion's trial, then, once the touches stop, a reach
to a seen target; the endpoint's bias against the drift.

The illusion's system (:func:`rhi.master.tasks.illusion.wiring.scenario`) runs to ``reach_after.release``; then the
touches stop, the load cell lets the hand go (``body.release_time``), and a target appears: the camera's image
of the arm at the target pose, the `rhi reach` attractor (docs/reach.md), through a
:class:`~rhi.components.brain.goal.GoalOnset`. The action law is the reach's (the released agent's integrator).
Measured: the drift at release, and the hand's x error from the target ``window`` seconds after release, signed
toward the rubber hand. Its settings: ``reach_after.toml`` (``[reach_after]``).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from rhi.components.body import kinematics
from rhi.components.body.arm_pose import PosedArm
from rhi.components.body.camera import Camera
from rhi.components.brain.goal import GoalOnset
from rhi.components.component import ComponentError
from rhi.master import config as configuration
from rhi.master import models
from rhi.master.cosim import ConfigError
from rhi.master.outputs import tables
from rhi.master.config.protocol import plan
from rhi.master.config.sources import parameters as task_parameters
from rhi.master.decoders.cache import checkpoint_path, decoder_component, per_decoder
from rhi.master.runtime.pool import JOB_THREADS, Workers
from rhi.master.tasks.base import Task, TaskResult
from rhi.master.tasks.illusion import wiring
from rhi.master.tasks.scene import Scenario, declared, run

NAME = "reach-after"
GOAL_LINKS = [("goal.pose", "goal_camera.arm_pose"), ("goal_camera.image", "goal_decoder.image"),
              ("brain.mu", "goal_decoder.mu"), ("goal_decoder.visual_drive", "goal_onset.drive"),
              ("goal_decoder.visual_error", "goal_onset.error"), ("goal_decoder.visual_stiffness", "goal_onset.stiffness"),
              ("goal_onset.goal_drive", "brain.goal_drive"), ("goal_onset.goal_error", "brain.goal_error"),
              ("goal_onset.goal_stiffness", "brain.goal_stiffness")]
RECORD = ("brain.mu", "brain.gamma", "body.q_shoulder", "body.q_elbow", "body.hand_x", "body.hand_y")
COLUMNS = ["decoder", "condition", "stimulation", "n_trials", "drift_at_release_cm_mean", "endpoint_bias_cm_mean",
           "endpoint_bias_cm_sd", "endpoint_error_cm_mean", "gamma_at_release_mean"]


def target_pose(config: dict) -> tuple[float, float]:
    """The target's joint angles: the resting hand moved by ``reach_after.target``.

    Returns
    -------
    tuple of float
        (shoulder, elbow) in deg, the hand at ``REST_HAND + target`` (m).
    """
    dx, dy = config["reach_after"]["target"]
    shoulder, elbow = kinematics.inverse(kinematics.REST_HAND[0] + dx, kinematics.REST_HAND[1] + dy)
    return float(shoulder), float(elbow)


def scenario(config: dict, kind: str, path: str) -> Scenario:
    """The task as data: the illusion's scenario of decoder ``kind`` (checkpoint ``path``) with the goal's arm,
    camera, decoder and onset added before the model."""
    illusion = wiring.scenario(decoder_component(kind, path, config, threads=JOB_THREADS), config,
                               trials=[t for t in plan(config) if t.decoder == kind])
    goal = (PosedArm("goal"), Camera("goal_camera", resolution=config["experiment"]["resolution"]),
            decoder_component(kind, path, config, threads=JOB_THREADS, name="goal_decoder"), GoalOnset())
    return dataclasses.replace(illusion, world=(*illusion.world, *goal), links=(*illusion.links, *GOAL_LINKS),
                               record=RECORD)


def parameters(trials: list, config: dict, system) -> dict:
    """The illusion's parameters of ``trials`` that ``system`` declares; the target pose (deg), the release (s),
    the goal image's variance (``decoder.visual_variance / reach_after.precision_ratio``) and the goal camera's."""
    given = declared(task_parameters(trials, config), system)
    shoulder, elbow = target_pose(config)
    after = config["reach_after"]
    given.update({"goal.shoulder": shoulder, "goal.elbow": elbow, "goal_onset.onset": after["release"],
                  "goal_decoder.visual_variance": config["decoder"]["visual_variance"] / after["precision_ratio"],
                  "goal_camera.blur": config["camera"]["blur"], "goal_camera.ball_radius": config["camera"]["ball_radius"]})
    return wiring.screen_parameters(given, system)


def simulate_trials(config: dict, kind: str, path: str):
    """The protocol's trials of decoder ``kind`` in one lockstep batch: (the trials, the master's Result)."""
    trials = [t for t in plan(config) if t.decoder == kind]
    return trials, run(scenario(config, kind, path), config, lambda system: parameters(trials, config, system),
                       len(trials), trials=trials)


def shipped_file() -> Path:
    """The shipped protocol file, master/tasks/reach_after.toml."""
    from importlib import resources
    return Path(str(resources.files("rhi.master.tasks").joinpath("reach_after.toml")))


def load(path=None, model_name: str = "paper", overrides: dict | None = None) -> dict:
    """The defaults, the model, the file's [reach_after] table and its other keys over them (the shipped file's
    first), then ``overrides`` (``{"reach_after.release": 1.0}``); checked."""
    config = configuration.defaults()
    config.pop("quick")
    config = configuration.with_model(config, model_name)
    shipped = configuration.read_toml(shipped_file())
    config = configuration.merge({**config, "reach_after": shipped.pop("reach_after")}, shipped)
    if path is not None:
        config = configuration.merge(config, configuration.read_toml(path))
    config = configuration.merge(config, configuration.nest(overrides or {}))
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
    trials, result = simulate_trials(config, kind, path)
    return trials, measures(result.times, result.values, config, trials)


def measures(times, values, config: dict, trials) -> dict:
    """Per trial: the drift and gamma at release; the hand's error from the target at the end (cm), and its x
    part signed toward the rubber hand (positive: toward it)."""
    release = int(np.argmin(np.abs(np.asarray(times) - config["reach_after"]["release"])))
    mu = values["brain.mu"]
    perceived, _ = kinematics.forward(mu[..., 0], mu[..., 1])
    real, _ = kinematics.forward(values["body.q_shoulder"], values["body.q_elbow"])
    target = np.array(kinematics.forward(*target_pose(config)))
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


class ReachAfter(Task):
    """Reaching after the illusion: the endpoint's bias against the drift (reach_after.csv)."""

    name = NAME
    summary = "the illusion's trial, then a reach to a target once the touches stop"
    command = f"rhi phenomenon {NAME}"
    settings = "reach_after.toml"

    def load(self, path=None, overrides: dict | None = None, quick: bool = False, model_name: str = "paper") -> dict:
        """:func:`load` (``quick`` does not apply: the protocol's file sets its size)."""
        return load(path, model_name, overrides)

    def plan(self, config: dict) -> list:
        """The illusion protocol's trials (:func:`rhi.master.config.protocol.plan`)."""
        return plan(config)

    def scenario(self, config: dict, kind: str, trials=(), checkpoint: str | None = None):
        """The reach-after system of decoder ``kind`` (:func:`scenario`)."""
        return scenario(config, kind, checkpoint or checkpoint_path(kind, config, must_exist=True))

    def parameters(self, trials: list, config: dict, system) -> dict:
        """The trials' parameters and the target's (:func:`parameters`)."""
        return parameters(trials, config, system)

    def measures(self, result, config: dict, trials: list) -> dict:
        """Per trial (not per step): :func:`measures`."""
        return measures(result.times, result.values, config, trials)

    def simulate(self, config: dict, context, workers=None) -> TaskResult:
        """Each decoder's trials in one lockstep batch, the decoders side by side."""
        if workers is None:
            with Workers() as own:
                return self.simulate(config, context, own)
        checkpoints, by_kind = per_decoder(config, decoder_trials, workers)
        trials = [t for batch, _ in by_kind.values() for t in batch]
        per_trial = {key: np.concatenate([values[key] for _, values in by_kind.values()])
                     for key in next(iter(by_kind.values()))[1]}
        provenance = {"command": self.command, "task": self.name, "model": models.of(config).name,
                      "configuration": config, "checkpoints": checkpoints, "seeds": [t.__dict__ for t in trials]}
        return TaskResult(self, config, trials, None, per_trial, provenance)

    def tables(self, result: TaskResult) -> dict:
        """reach_after.csv: per decoder x condition x stimulation, drift at release and endpoint bias (:func:`rows`)."""
        kinds = list(dict.fromkeys(trial.decoder for trial in result.trials))
        found = []
        for kind in kinds:
            members = [i for i, t in enumerate(result.trials) if t.decoder == kind]
            found.append(([result.trials[i] for i in members],
                          {key: np.asarray(values)[members] for key, values in result.per_step.items()}))
        return {"reach_after.csv": tables.csv_text(COLUMNS, rows(found))}
