"""The causal model's system: the paper's components with the pose encoder and the causal brain.

Connections: the paper's (:data:`master.experiment.wiring.CONNECTIONS`) less every link that
would hand the brain a simulator position (the rubber hand, the body's hand), plus the camera's
image into the pose encoder and its pose and variance into the brain. The parameters the causal
brain declares that the paper's brain has come from ``[brain]`` as for the paper; the rest from
``[causal]`` (:data:`PARAMETER_SOURCES`) or derived here.
"""
from __future__ import annotations

import numpy as np

from components.body import kinematics
from components.brain.causal_brain import CausalBrain
from master.experiment import training_data
from master.experiment.protocol import per_trial

GROUND_TRUTH_LINKS = ("rubber_arm.hand", "body.hand_x", "body.hand_y")  # never into the causal brain
EXTRA_CONNECTIONS = [("camera.image", "pose_encoder.image"), ("pose_encoder.pose", "brain.seen_pose"),
                     ("pose_encoder.pose_variance", "brain.seen_pose_variance")]
EXTRA_RECORD = ["brain.gamma_timing"]

PARAMETER_SOURCES = {
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


def components(decoder, config: dict, paper_connections: list, body):
    """The causal system's components around ``decoder`` (its kind picks the pose encoder), and its connections:
    ``paper_connections`` (the paper's system's) less the ground-truth links, plus the pose encoder's."""
    from components.body.camera import Camera
    from components.body.plant import ArmPlant
    from components.body.rubber_arm import RubberArm
    from components.stimulus import Stimulus
    from components.vision.pose_encoder import PoseEncoder, load_encoder
    from master.experiment.pose_encoders import encoder_path

    kind = decoder.model.metadata.get("kind", "conv")
    resolution = config["experiment"]["resolution"]
    encoder = PoseEncoder(load_encoder(encoder_path(kind, config)), resolution=resolution,
                          threads=getattr(decoder, "threads", None))
    parts = [RubberArm(), Stimulus(), Camera(resolution=resolution), decoder, encoder, CausalBrain(),
             body if body is not None else ArmPlant()]
    links = [(a, b) for a, b in paper_connections if not (b.startswith("brain.") and a in GROUND_TRUTH_LINKS)]
    return parts, links + EXTRA_CONNECTIONS


def parameters(trials, config: dict, paper_given: dict) -> dict:
    """The causal brain's parameters (and every other component's, as for the paper)."""
    declared = set(CausalBrain().variables)
    given = {path: value for path, value in paper_given.items()
             if not path.startswith("brain.") or path.partition(".")[2] in declared}
    for path, source in PARAMETER_SOURCES.items():
        if not source.startswith(("derived", "per trial")):
            given[path] = per_trial(trials, config, source)
    spread = per_trial(trials, config, DERIVED_FROM)
    given["brain.coupling_sd"] = (np.stack([coupling_sd(value) for value in spread]) if np.ndim(spread)
                                  else coupling_sd(spread))
    given["brain.workspace_mean"] = np.array(kinematics.REST_POSE, dtype=float)
    given["brain.workspace_sd"] = np.array(training_data.HALF_RANGES, dtype=float) / np.sqrt(3.0)
    given["brain.participant_seed"] = np.array([t.seed for t in trials], dtype=np.int64)
    return given
