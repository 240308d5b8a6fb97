"""The moving-hand task: the real arm (free) swings by itself at the shoulder; the rubber arm, the only arm in
view, repeats the movement after a delay per trial; no touch.

The brain perceives (its action is not fed to the body: the movement is the participant's own); the seen and
felt turning points of the movement stand in for the touches (:mod:`rhi.components.brain.turning_points`). The
protocol and its report: :mod:`rhi.master.phenomena.moving_hand`.
"""
from __future__ import annotations

import numpy as np

from rhi.components.body.camera import Camera
from rhi.components.body.movement import MirroredArm, Movement
from rhi.components.body.plant import ArmPlant
from rhi.components.brain.turning_points import TurningPoints
from rhi.master.config.protocol import rubber_pose, trial_seed
from rhi.master.config.sources import model_parameters, shared_parameters
from rhi.master.decoders.cache import decoder_component
from rhi.master.runtime.pool import JOB_THREADS
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
