"""The moving-hand task: the real arm (free) swings by itself at the shoulder; the rubber arm, the only arm in
view, repeats the movement after a delay per trial; no touch.

The brain perceives (its action is not fed to the body: the movement is the participant's own, and the released
agent's illusion task ran without action); the seen and felt turning points of the movement stand in for the
touches (:mod:`rhi.components.brain.turning_points`): its gamma weighs the delay between them by eqs. 8-9. Drift and
gamma are the means over the last movement period. Its settings: ``moving_hand.toml`` (``[moving_hand]``); its
figure beside the human references: :mod:`rhi.master.phenomena.moving_hand`.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rhi.components.body import kinematics
from rhi.components.body.camera import Camera
from rhi.components.body.movement import MirroredArm, Movement
from rhi.components.body.plant import ArmPlant
from rhi.components.brain.turning_points import TurningPoints
from rhi.master import config as configuration
from rhi.master import models
from rhi.master.config import population
from rhi.master.config.protocol import rubber_pose, trial_seed
from rhi.master.cosim import ConfigError
from rhi.master.outputs import tables
from rhi.master.config.sources import model_parameters, shared_parameters
from rhi.master.decoders.cache import checkpoint_path, decoder_component, per_decoder
from rhi.master.runtime.pool import JOB_THREADS
from rhi.master.runtime.pool import Workers
from rhi.master.tasks.base import Task, TaskResult
from rhi.master.tasks.scene import Scenario, declared, run

NAME = "moving-hand"
CONNECTIONS = [
    ("body.q_shoulder", "rubber_arm.q_shoulder"), ("body.q_elbow", "rubber_arm.q_elbow"),
    ("rubber_arm.pose", "turning_points.seen_pose"), ("body.q_shoulder", "turning_points.q_shoulder"),
    ("rubber_arm.pose", "camera.arm_pose"), ("camera.image", "decoder.image"), ("brain.mu", "decoder.mu"),
    ("decoder.visual_drive", "brain.visual_drive"), ("decoder.visual_error", "brain.visual_error"),
    ("decoder.visual_stiffness", "brain.visual_stiffness"),
    ("turning_points.visual_time", "brain.visual_time"), ("turning_points.tactile_time", "brain.tactile_time"),
    ("body.q_shoulder", "brain.q_shoulder"), ("body.q_elbow", "brain.q_elbow"),
    ("movement.u_shoulder", "body.u_shoulder"), ("movement.u_elbow", "body.u_elbow")]
RECORD = ("brain.mu", "brain.gamma", "body.q_shoulder", "body.q_elbow")
COLUMNS = ["decoder", "delay_s", "drift_cm", "drift_relative", "gamma", "gamma_relative"]


@dataclass(frozen=True)
class Delay:
    """One trial: decoder ``decoder``'s run at a visuomotor ``delay`` (s), drawn with ``seed``."""

    decoder: str
    delay: float
    seed: int


def seeds(config: dict, delays: list[float]) -> list[int]:
    """A seed per delay (a model of a population draws each trial's participant from it)."""
    return [trial_seed(config["experiment"]["seed"], NAME, f"{delay:g}", index) for index, delay in enumerate(delays)]


def parameters(config: dict, delays: list[float]) -> dict:
    """The body's, camera's and decoder's parameters as the experiment gives them, the model's brain's; the
    rubber arm at the condition's rest pose; the delays per trial (s); the free body."""
    given = shared_parameters(config, ("body", "camera", "decoder"))
    given.update(model_parameters(config, seeds(config, delays), lambda key: config[key.split(".")[0]][key.split(".")[1]]))
    moving = config["moving_hand"]
    shoulder, elbow = rubber_pose(config["conditions"][moving["condition"]], config["rubber_arm"]["offset_y"])
    given.update({"body.held": False, "rubber_arm.delay": np.array(delays, dtype=float),
                  "rubber_arm.rest_shoulder": shoulder, "rubber_arm.rest_elbow": elbow,
                  "movement.amplitude": moving["amplitude"], "movement.period": moving["period"]})
    return given


def scenario(config: dict, kind: str, path: str) -> Scenario:
    """The task as data: the movement, the mirrored rubber arm, the turning points, the camera and the decoder
    (``kind``, checkpoint ``path``) before the model; the free body after it."""
    experiment = config["experiment"]
    return Scenario(world=(Movement(), MirroredArm(step_size=experiment["step_size"]), TurningPoints(),
                           Camera(resolution=experiment["resolution"]),
                           decoder_component(kind, path, config, threads=JOB_THREADS)),
                    body=(ArmPlant(),), links=tuple(CONNECTIONS), record=RECORD, kind=kind, threads=JOB_THREADS,
                    pixel_term=("decoder",))


def simulate_delays(config: dict, kind: str, path: str):
    """Every delay of ``moving_hand.delays`` with one decoder, in one lockstep batch; the master's Result."""
    delays = list(config["moving_hand"]["delays"])
    return run(scenario(config, kind, path), config, lambda system: declared(parameters(config, delays), system),
               len(delays))


def shipped_file() -> Path:
    """The shipped protocol file, master/tasks/moving_hand.toml."""
    from importlib import resources
    return Path(str(resources.files("rhi.master.tasks").joinpath("moving_hand.toml")))


def load(path=None, model_name: str = "paper", overrides: dict | None = None) -> dict:
    """The defaults, the model, and the protocol's [moving_hand] table (and any other keys of the file) over them,
    then ``overrides`` (``{"moving_hand.delays": [0.0]}``); checked."""
    given = configuration.read_toml(path if path is not None else shipped_file())
    protocol = given.pop("moving_hand", None)
    if not isinstance(protocol, dict):
        raise ConfigError(f"{path}: a moving-hand file needs a [moving_hand] table (copy {shipped_file()})")
    shipped = configuration.read_toml(shipped_file())["moving_hand"]
    config = configuration.defaults()
    config.pop("quick")
    config = configuration.with_model(config, model_name)
    config = configuration.merge({**config, "moving_hand": shipped}, {"moving_hand": protocol, **given})
    config = configuration.merge(config, configuration.nest(overrides or {}))
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
    result = simulate_delays(config, kind, path)
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


class MovingHand(Task):
    """The moving rubber hand: drift and common-cause belief per visuomotor delay (moving_hand.csv)."""

    name = NAME
    summary = "the free arm swinging, the rubber arm repeating the movement after a delay, no touch"
    command = f"rhi phenomenon {NAME}"
    settings = "moving_hand.toml"

    def load(self, path=None, overrides: dict | None = None, quick: bool = False, model_name: str = "paper") -> dict:
        """:func:`load` (``quick`` does not apply: the protocol's file sets its size)."""
        return load(path, model_name, overrides)

    def plan(self, config: dict) -> list[Delay]:
        """A :class:`Delay` per decoder and ``moving_hand.delays`` entry, each with its seed."""
        delays = list(config["moving_hand"]["delays"])
        return [Delay(kind, delay, seed) for kind in config["experiment"]["decoders"]
                for delay, seed in zip(delays, seeds(config, delays))]

    def scenario(self, config: dict, kind: str, trials=(), checkpoint: str | None = None) -> Scenario:
        """The moving-hand system of decoder ``kind`` (:func:`scenario`)."""
        return scenario(config, kind, checkpoint or checkpoint_path(kind, config, must_exist=True))

    def parameters(self, trials: list, config: dict, system) -> dict:
        """The system's parameters for the trials' delays (:func:`parameters`)."""
        return declared(parameters(config, [trial.delay for trial in trials]), system)

    def measures(self, result, config: dict, trials: list) -> dict:
        """Per delay (not per step): :func:`measures`."""
        return measures(result.times, result.values, config["moving_hand"]["period"])

    def simulate(self, config: dict, context, workers=None) -> TaskResult:
        """Each decoder's delays in one lockstep batch, the decoders side by side."""
        if workers is None:
            with Workers() as own:
                return self.simulate(config, context, own)
        checkpoints, found = per_decoder(config, decoder_delays, workers)
        trials = self.plan(config)
        per_trial = {key: np.concatenate([found[kind][key] for kind in found]) for key in ("drift_cm", "gamma")}
        provenance = {"command": self.command, "task": self.name, "model": models.of(config).name,
                      "configuration": config, "checkpoints": checkpoints}
        return TaskResult(self, config, trials, None, per_trial, provenance)

    def found(self, result: TaskResult) -> dict[str, dict]:
        """Decoder -> :func:`measures` of its delays, from ``result``."""
        kinds = list(dict.fromkeys(trial.decoder for trial in result.trials))
        return {kind: {key: np.asarray(values)[[i for i, t in enumerate(result.trials) if t.decoder == kind]]
                       for key, values in result.per_step.items()} for kind in kinds}

    def tables(self, result: TaskResult) -> dict:
        """moving_hand.csv: drift and gamma per decoder and delay, and each relative to 0 s (:func:`rows`)."""
        return {"moving_hand.csv": tables.csv_text(COLUMNS, rows(result.config, self.found(result)))}
