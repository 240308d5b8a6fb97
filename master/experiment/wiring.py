"""The rubber-hand system: its components, their connections in step order, and their parameters."""
from __future__ import annotations

import numpy as np

from components.body import kinematics
from components.body.camera import Camera
from components.body.plant import ArmPlant
from components.body.rubber_arm import RubberArm
from components.brain.integrator import Brain
from components.stimulus import Stimulus
from master.cosim import System, simulate
from master.experiment.protocol import Trial

# Gauss-Seidel order within one step (DESIGN.md): the decoder reads the brain's mu of time t and the
# image of time t; the brain then integrates; the body finally receives the new action.
CONNECTIONS = [
    ("rubber_arm.hand", "stimulus.target"),
    ("rubber_arm.pose", "camera.arm_pose"),
    ("stimulus.ball", "camera.ball"),
    ("camera.image", "decoder.image"),
    ("brain.mu", "decoder.mu"),
    ("decoder.visual_drive", "brain.visual_drive"),
    ("decoder.visual_error", "brain.visual_error"),
    ("decoder.visual_stiffness", "brain.visual_stiffness"),
    ("stimulus.visual_time", "brain.visual_time"),
    ("stimulus.tactile_time", "brain.tactile_time"),
    ("body.q_shoulder", "brain.q_shoulder"),
    ("body.q_elbow", "brain.q_elbow"),
    ("brain.u_shoulder", "body.u_shoulder"),
    ("brain.u_elbow", "body.u_elbow"),
]

RECORD = ["brain.mu", "brain.gamma", "brain.u_shoulder", "brain.u_elbow", "brain.action_rate",
          "brain.free_energy", "body.q_shoulder", "body.q_elbow", "body.hand_x", "body.hand_y",
          "body.force_x", "body.force_y", "stimulus.visual_time", "stimulus.tactile_time",
          "decoder.visual_error", "stimulus.ball"]


def build_system(decoder, config: dict, body=None) -> System:
    """The rubber-hand system around a decoder component; ``body`` defaults to the native pymunk plant."""
    resolution = config["experiment"]["resolution"]
    components = [RubberArm(), Stimulus(), Camera(resolution=resolution), decoder, Brain(),
                  body if body is not None else ArmPlant()]
    return System(components, CONNECTIONS)


def parameters(trials: list[Trial], config: dict) -> dict:
    """Per-trial and shared parameters, as ``component.variable`` paths."""
    column = lambda attribute: np.array([getattr(t, attribute) for t in trials])  # noqa: E731
    brain, body = config["brain"], config["body"]
    return {
        "rubber_arm.offset_x": column("offset_x"),
        "stimulus.period": config["stimulus"]["period"],
        "stimulus.delay_min": column("delay_min"),
        "stimulus.delay_max": column("delay_max"),
        "stimulus.seed": column("seed").astype(np.int64),
        "decoder.visual_variance": config["decoder"]["visual_variance"],
        "brain.mu0": np.array(kinematics.REST_POSE, dtype=float),
        "brain.proprioceptive_variance": brain["proprioceptive_variance"],
        "brain.gamma0": brain["gamma0"],
        "brain.sync_sd": brain["sync_sd"],
        "brain.async_density": brain["async_density"],
        "brain.decay_rate": brain["decay_rate"],
        "body.held": bool(body["held"]),
        "body.substeps": int(body["substeps"]),
    }


def run_batch(decoder, trials: list[Trial], config: dict, body=None, progress=None):
    """Run ``trials`` (all with this decoder component) in lockstep; returns the master's Result."""
    experiment = config["experiment"]
    system = build_system(decoder, config, body)
    return simulate(system, stop_time=experiment["steps"] * experiment["step_size"],
                    step_size=experiment["step_size"], scheme=experiment["scheme"], batch_size=len(trials),
                    parameters=parameters(trials, config), record=RECORD, progress=progress)


