"""The rubber-hand system: its components, their connections in step order, and one lockstep batch of it.

Its parameters come from :mod:`rhi.master.config.sources` (their table and values).
"""
from __future__ import annotations

from rhi.components.body.camera import Camera
from rhi.components.body.plant import ArmPlant
from rhi.components.body.rubber_arm import RubberArm
from rhi.components.screen import Screen
from rhi.components.stimulus import Stimulus
from rhi.master import models
from rhi.master.cosim import System
from rhi.master.config.protocol import Trial, plan, table_rows
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


# While the rubber arm is out of view for part of a trial, the image seen is a screen's: the camera's, or a second
# camera's drawing of the scene without the arm (the ball alone), as the stimulus generator's schedule says.
SCREEN_LINKS = [
    ("rubber_arm.pose", "ball_camera.arm_pose"),
    ("stimulus.ball", "ball_camera.ball"),
    ("camera.image", "screen.image"),
    ("ball_camera.image", "screen.ball_image"),
    ("stimulus.arm_visible", "screen.arm_visible"),
]


def screened(config: dict, trials=()) -> bool:
    """Whether a trial of ``config`` (or of ``trials``) hides the rubber arm for part of its time (hidden times, or
    readings that hide it), so that the seen image passes through a screen."""
    return any(trial.hidden for trial in (*plan(config), *trials))


def scenario(decoder, config: dict, body=None, trials=()) -> Scenario:
    """The rubber-hand task as data: the rubber arm, the stimulus (its tables as long as the protocol's schedules
    need), the camera (and the screen, when the arm is hidden for part of a trial) and ``decoder`` before the model,
    ``body`` (default: the native pymunk plant) after it, :data:`CONNECTIONS`, and :data:`RECORD` with the
    model's own paths."""
    kind = decoder.model.metadata.get("kind", "conv") if hasattr(decoder, "model") else "conv"
    resolution = config["experiment"]["resolution"]
    blocks, hidden = table_rows(config, trials)
    world, links, seen = [RubberArm(), Stimulus(blocks=blocks, hidden=hidden), Camera(resolution=resolution)], \
        list(CONNECTIONS), "camera.image"
    if screened(config, trials):
        world += [Camera("ball_camera", resolution=resolution), Screen(resolution=resolution)]
        seen = "screen.seen"
        links = [*SCREEN_LINKS, *((seen if source == "camera.image" else source, target) for source, target in links)]
    return Scenario(world=(*world, decoder), body=(body if body is not None else ArmPlant(),), links=tuple(links),
                    record=(*RECORD, *models.of(config).record), kind=kind, threads=getattr(decoder, "threads", None),
                    pixel_term=("decoder",), seen_image=seen)


def screen_parameters(given: dict, system: System) -> dict:
    """``given`` with the ball camera's parameters when ``system`` has one: the camera's blur and ball radius, and
    no arm (it draws the scene without the rubber arm)."""
    if "ball_camera" in system.components:
        given = {**given, "ball_camera.blur": given["camera.blur"], "ball_camera.ball_radius": given["camera.ball_radius"],
                 "ball_camera.arm_visible": False}
    return given


def build_system(decoder, config: dict, body=None, trials=()) -> System:
    """The rubber-hand system around a decoder component, with the configuration's model (its parts and brain);
    ``body`` defaults to the native pymunk plant."""
    return build(scenario(decoder, config, body, trials), config, trials)


def system_parameters(trials: list[Trial], config: dict, system: System, given: dict | None = None) -> dict:
    """The parameters of ``trials`` (``given``: :func:`rhi.master.config.sources.parameters` of them, computed when
    None) that ``system`` declares, with the ball camera's (:func:`screen_parameters`)."""
    given = parameters(trials, config) if given is None else given
    dropped = set(undeclared(given, system))
    return screen_parameters({path: value for path, value in given.items() if path not in dropped}, system)


def run_batch(decoder, trials: list[Trial], config: dict, body=None, progress=None):
    """Run ``trials`` (all with this decoder component) in lockstep; returns the master's Result."""
    given = parameters(trials, config)
    return run(scenario(decoder, config, body, trials), config,
               lambda system: system_parameters(trials, config, system, given), len(trials), progress, trials)
