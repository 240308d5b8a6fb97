"""The rubber-hand system: its components, their connections in step order, and one lockstep batch of it.

Its parameters come from :mod:`master.config.sources` (their table and values; the names it uses are
importable from here too, where callers of the system find them).
"""
from __future__ import annotations

import numpy as np

from components.body.camera import Camera
from components.body.plant import ArmPlant
from components.body.rubber_arm import RubberArm
from components.stimulus import Stimulus
from master import models
from master.cosim import ConfigError, System, simulate
from master.config.protocol import Trial
from master.config.sources import (CONSTRUCTED, DERIVED, PARAMETER_SOURCES, PER_TRIAL, TASK_SOURCES,  # noqa: F401
                                   batchable_keys, check_parameters, config_key, parameters, shared_parameters,
                                   undeclared)
from master.tasks.scene import assemble, model_parts

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


def build_system(decoder, config: dict, body=None) -> System:
    """The rubber-hand system around a decoder component, with the configuration's model (its parts and brain);
    ``body`` defaults to the native pymunk plant."""
    model = models.of(config)
    kind = decoder.model.metadata.get("kind", "conv") if hasattr(decoder, "model") else "conv"
    parts = [RubberArm(), Stimulus(), Camera(resolution=config["experiment"]["resolution"]), decoder,
             *model_parts(config, kind, getattr(decoder, "threads", None)), body if body is not None else ArmPlant()]
    return assemble(parts, CONNECTIONS + list(model.links))


def run_batch(decoder, trials: list[Trial], config: dict, body=None, progress=None):
    """Run ``trials`` (all with this decoder component) in lockstep; returns the master's Result."""
    experiment = config["experiment"]
    system = build_system(decoder, config, body)
    given = parameters(trials, config)
    for path in undeclared(given, system):
        del given[path]
    return simulate(system, stop_time=experiment["steps"] * experiment["step_size"],
                    step_size=experiment["step_size"], scheme=experiment["scheme"], batch_size=len(trials),
                    parameters=given, record=RECORD + list(models.of(config).record), progress=progress)


