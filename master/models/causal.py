"""The causal model: the seen arm's pose from a pose encoder, causal inference over space and time, a
persistent common-cause state and a population of participants (docs/model.md).

Its system is a task's with the pose encoder added (the camera's image in, the seen pose and its variance
into the brain) and the causal brain in the paper brain's place. The causal brain declares no input for a
simulator position, so the task's links that would hand it one (the rubber hand, the body's hand) are left
out by the assembly (:func:`rhi.master.tasks.scene.assemble`). Its parameters the paper's brain also has come
from ``[brain]`` as for the paper; the rest from ``[causal]`` (master/models/causal.toml) or derived here.
"""
from __future__ import annotations

import numpy as np

from rhi.components.body import kinematics
from rhi.master.models.base import Model, TrialValues
from rhi.master.models.paper import rest_belief, with_paper_sources

OWN_SOURCES = {
    "brain.pixel_weight": "causal.pixel_weight",
    "brain.common_cause_prior": "causal.common_cause_prior",
    "brain.switching_time": "causal.switching_time",
    "brain.timing_noise_sd": "causal.timing_noise_sd",
    "brain.timing_noise_log_sd": "causal.timing_noise_log_sd",
    "brain.switching_log_sd": "causal.switching_log_sd",
    "brain.coupling_log_sd": "causal.peripersonal_log_sd",
    "brain.prior_concentration": "causal.prior_concentration",
    "brain.coupling_sd": "derived: causal.peripersonal_sd (m) in joint degrees at the rest pose (coupling_sd)",
    "brain.workspace_mean": "derived: the rest pose (the centre of the training ranges)",
    "brain.workspace_sd": "derived: the training ranges' half widths / sqrt(3), the sd of the uniform over them",
    "brain.participant_seed": "per trial: the trial's seed (its own stream, body_inference.participants)",
}
DERIVED_FROM = "causal.peripersonal_sd"  # the key brain.coupling_sd is derived from


def coupling_sd(peripersonal_sd: float) -> np.ndarray:
    """(2,) deg: sqrt of the diagonal of J^-1 (s^2 I) J^-T, the isotropic hand spread s (m) in joint angles at rest."""
    jacobian = kinematics.jacobian(*kinematics.REST_POSE)  # m/deg
    inverse = np.linalg.inv(jacobian)
    return np.sqrt(np.diag(inverse @ inverse.T)) * peripersonal_sd


def _brain_class():
    from rhi.components.brain.causal_brain import CausalBrain
    return CausalBrain


class CausalModel(Model):
    """The causal brain (:class:`rhi.components.brain.causal_brain.CausalBrain`) with the pose encoder."""

    name = "causal"
    summary = "the causal model: body-space vision, causal inference over space and time, a population"
    settings_file = "causal.toml"
    sees_pose = True
    pose_encoder_key = "causal.{kind}_pose_encoder"
    batchable = (DERIVED_FROM,)
    links = (("camera.image", "pose_encoder.image"), ("pose_encoder.pose", "brain.seen_pose"),
             ("pose_encoder.pose_variance", "brain.seen_pose_variance"))
    record = ("brain.gamma_timing",)

    def brain(self):
        """A new :class:`~rhi.components.brain.causal_brain.CausalBrain`."""
        return _brain_class()()

    @property
    def parameter_sources(self) -> dict:
        """The paper's brain's sources of the parameters the causal brain also declares, and its own."""
        return with_paper_sources(_brain_class()(), OWN_SOURCES)

    def parameters(self, trials: TrialValues) -> dict:
        """The plain sources' values, and the derived ones: coupling_sd per trial, the workspace, the seeds."""
        given = {**super().parameters(trials), "brain.mu0": rest_belief(trials)}
        spread = trials.value(DERIVED_FROM)
        given["brain.coupling_sd"] = (np.stack([coupling_sd(value) for value in spread]) if np.ndim(spread)
                                      else coupling_sd(spread))
        given["brain.workspace_mean"] = np.array(trials.rest_pose, dtype=float)
        given["brain.workspace_sd"] = np.array(trials.half_ranges, dtype=float) / np.sqrt(3.0)
        given["brain.participant_seed"] = np.asarray(trials.seeds, dtype=np.int64)
        return given

    def trials_per_point(self, config: dict) -> int | None:
        """``causal.participants``: one simulated participant a trial."""
        return config["causal"]["participants"]

    def reads_pixels(self, config: dict) -> bool:
        """Only when ``causal.pixel_weight`` > 0."""
        return config["causal"]["pixel_weight"] > 0
