"""The reach-after task: the illusion's trial, then, once the touches stop, a reach to a seen target.

The illusion's system (:func:`rhi.master.tasks.illusion.wiring.scenario`) runs to ``reach_after.release``; then the
touches stop, the load cell lets the hand go (``body.release_time``), and a target appears: the camera's image
of the arm at the target pose, the `rhi reach` attractor (docs/reach.md), through a
:class:`~rhi.components.brain.goal.GoalOnset`. The protocol and its report: :mod:`rhi.master.phenomena.reach_after`.
"""
from __future__ import annotations

import dataclasses

from rhi.components.body import kinematics
from rhi.components.body.arm_pose import PosedArm
from rhi.components.body.camera import Camera
from rhi.components.brain.goal import GoalOnset
from rhi.master.config.protocol import plan
from rhi.master.config.sources import parameters as task_parameters
from rhi.master.decoders.cache import decoder_component
from rhi.master.runtime.pool import JOB_THREADS
from rhi.master.tasks.illusion import wiring
from rhi.master.tasks.scene import Scenario, declared, run

NAME = "reach-after"
GOAL_LINKS = [("goal.pose", "goal_camera.arm_pose"), ("goal_camera.image", "goal_decoder.image"),
              ("brain.mu", "goal_decoder.mu"), ("goal_decoder.visual_drive", "goal_onset.drive"),
              ("goal_decoder.visual_error", "goal_onset.error"), ("goal_decoder.visual_stiffness", "goal_onset.stiffness"),
              ("goal_onset.goal_drive", "brain.goal_drive"), ("goal_onset.goal_error", "brain.goal_error"),
              ("goal_onset.goal_stiffness", "brain.goal_stiffness")]
RECORD = ("brain.mu", "brain.gamma", "body.q_shoulder", "body.q_elbow", "body.hand_x", "body.hand_y")


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
