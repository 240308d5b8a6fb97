"""What a trial measures (DESIGN.md, Measures), per step and trial, from the recorded outputs."""
from __future__ import annotations

import numpy as np

from components.body import kinematics

def measures(result) -> dict[str, np.ndarray]:
    """Per step and trial (shape steps+1 x B): drift (cm), force (N), attempted hand velocity, and the rest.

    Drift = x of the perceived hand (forward kinematics of mu) minus x of the real hand, in cm;
    negative is to the left (DESIGN.md, Measures).
    """
    values = result.values
    mu = values["brain.mu"]
    perceived_x, _ = kinematics.forward(mu[..., 0], mu[..., 1])
    real_x, _ = kinematics.forward(values["body.q_shoulder"], values["body.q_elbow"])
    jacobian = kinematics.jacobian(values["body.q_shoulder"], values["body.q_elbow"])  # m/deg
    attempted = np.einsum("...ij,...j->...i", jacobian, values["brain.action_rate"])
    return {
        "drift_cm": 100.0 * (perceived_x - real_x),
        "force_x_n": values["body.force_x"],
        "force_y_n": values["body.force_y"],
        "gamma": values["brain.gamma"],
        "mu_shoulder_deg": mu[..., 0],
        "mu_elbow_deg": mu[..., 1],
        "s_p_shoulder_deg": values["body.q_shoulder"],
        "s_p_elbow_deg": values["body.q_elbow"],
        "action_shoulder_deg_s": values["brain.u_shoulder"],
        "action_elbow_deg_s": values["brain.u_elbow"],
        "action_rate_shoulder": values["brain.action_rate"][..., 0],
        "action_rate_elbow": values["brain.action_rate"][..., 1],
        "attempted_hand_vx_m_s": attempted[..., 0],
        "visual_time_s": values["stimulus.visual_time"],
        "tactile_time_s": values["stimulus.tactile_time"],
        "visual_error": values["decoder.visual_error"],
        "free_energy": values["brain.free_energy"],
        "ball_x_m": values["stimulus.ball"][..., 0],
        "ball_y_m": values["stimulus.ball"][..., 1],
    }

