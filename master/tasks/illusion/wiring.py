"""The rubber-hand system: its components, their connections in step order, and one lockstep batch of it.

Its parameters come from :mod:`rhi.master.config.sources` (their table and values).
"""
from __future__ import annotations

import numpy as np

from rhi.components.body.camera import Camera
from rhi.components.body.plant import ArmPlant
from rhi.components.body.rubber_arm import RubberArm
from rhi.components.stimulus import Stimulus
from rhi.master import models
from rhi.master.cosim import System
from rhi.master.config.protocol import Trial
from rhi.master.config.sources import parameters, undeclared
from rhi.master.tasks.scene import Scenario, build, run

# Gauss-Seidel order within one step (docs/design.md): the decoder reads the brain's mu of time t and the
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
    ("rubber_arm.hand", "brain.seen_hand"),            # read only by the spatial extension (brain.spatial_sd)
    ("body.hand_x", "brain.hand_x"),
    ("body.hand_y", "brain.hand_y"),
    ("body.q_shoulder", "brain.q_shoulder"),
    ("body.q_elbow", "brain.q_elbow"),
    ("brain.u_shoulder", "body.u_shoulder"),
    ("brain.u_elbow", "body.u_elbow"),
]

RECORD = ["brain.mu", "brain.gamma", "brain.u_shoulder", "brain.u_elbow", "brain.action_rate",
          "brain.free_energy", "body.q_shoulder", "body.q_elbow", "body.hand_x", "body.hand_y",
          "body.force_x", "body.force_y", "stimulus.visual_time", "stimulus.tactile_time",
          "decoder.visual_error", "stimulus.ball"]


def scenario(decoder, config: dict, body=None) -> Scenario:
    """The rubber-hand task as data: the rubber arm, the stimulus, the camera and ``decoder`` before the model,
    ``body`` (default: the native pymunk plant) after it, :data:`CONNECTIONS`, and :data:`RECORD` with the
    model's own paths."""
    kind = decoder.model.metadata.get("kind", "conv") if hasattr(decoder, "model") else "conv"
    return Scenario(world=(RubberArm(), Stimulus(), Camera(resolution=config["experiment"]["resolution"]), decoder),
                    body=(body if body is not None else ArmPlant(),), links=tuple(CONNECTIONS),
                    record=(*RECORD, *models.of(config).record), kind=kind, threads=getattr(decoder, "threads", None),
                    pixel_term=("decoder",))


def build_system(decoder, config: dict, body=None) -> System:
    """The rubber-hand system around a decoder component, with the configuration's model (its parts and brain);
    ``body`` defaults to the native pymunk plant."""
    return build(scenario(decoder, config, body), config)


def run_batch(decoder, trials: list[Trial], config: dict, body=None, progress=None):
    """Run ``trials`` (all with this decoder component) in lockstep; returns the master's Result."""
    given = parameters(trials, config)

    def declared_by(system: System) -> dict:
        dropped = set(undeclared(given, system))
        return {path: value for path, value in given.items() if path not in dropped}
    return run(scenario(decoder, config, body), config, declared_by, len(trials), progress, trials)
