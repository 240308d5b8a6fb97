"""The causal model's brain: belief mu from proprioception and the seen arm's pose, weighted by gamma.

Each step, for each of the B trials (docs/model.md):

1. gamma_timing <- :func:`~rhi.components.brain.body_inference.hazard_predict` (the common-cause state
   persists, relaxing to its prior over ``switching_time``); at a new visuo-tactile pair it is
   updated by the perceived delay's likelihood ratio (the delay plus this participant's timing noise);
2. gamma = posterior(gamma_timing, spatial likelihood ratio of the seen pose x_v and the felt pose s_p);
3. mu_dot = (s_p - mu)/Sigma_p + gamma (x_v - mu)/Sigma_x + pixel_weight * gamma * visual_drive
   (:func:`belief_rate`): x_v and Sigma_x (deg, deg^2 per joint) come from the pose encoder;
4. a_dot and the action as in the paper's brain: the guards, the Euler step and the action law are every
   brain's (:class:`~rhi.components.brain.base.BeliefBrain`); this model computes gamma, mu_dot and F
   (:meth:`CausalBrain.rate`).

A reach goal's pull (input ``goal_drive``, docs/reach.md) is added to mu_dot unweighted by gamma, as in the
paper's brain; it is 0 (no goal) unless the reach task connects it.

The brain reads no position from the simulator: the seen arm reaches it only through the camera's
image and the pose encoder, the felt arm only as the sensed joint angles s_p. Each trial is one
participant: its parameters are drawn from the population once, at initialization, from its
``participant_seed`` (:func:`~rhi.components.brain.body_inference.participants`).
"""
from __future__ import annotations

import numpy as np

from .body_inference import hazard_predict, participants, posterior, spatial_likelihood_ratio, \
    timing_likelihood_ratio
from .action_law import add_goal_drive
from .base import BeliefBrain, BeliefRate, PerceptualNoise, require_finite
from .contract import JOINT, STATE, pixel_inputs
from ..component import ComponentError, StepFailure
from ..variables import Variable


def belief_rate(s_p, mu, gamma, seen_pose, seen_variance, proprioceptive_variance, pixel_weight, visual_drive):
    """mu_dot = (s_p - mu)/Sigma_p + gamma (x_v - mu)/Sigma_x + w gamma J^T (s_v - g(mu))/Sigma_v.

    The gradient of the free energy of two Gaussian observations of the arm's joint angles, the felt
    s_p (variance Sigma_p, the paper's eq. 6 term) and the seen x_v (the pose encoder's calibrated
    variance Sigma_x), the seen one weighted by gamma; w = pixel_weight adds the paper's pixel term
    (docs/model.md, "The causal model").

    Parameters
    ----------
    s_p, mu, seen_pose : ndarray, (B, 2)
        Sensed joint angles, belief, the seen pose x_v; deg.
    gamma, proprioceptive_variance, pixel_weight : ndarray, (B,)
        gamma (1), Sigma_p (deg^2), w (1).
    seen_variance : ndarray, (B, 2)
        Sigma_x, deg^2.
    visual_drive : ndarray, (B, 2)
        The paper's pixel term J^T (s_v - g(mu))/Sigma_v, deg/s.

    Returns
    -------
    ndarray, (B, 2)
        mu_dot, deg/s.
    """
    return ((s_p - mu) / proprioceptive_variance[:, None] + gamma[:, None] * (seen_pose - mu) / seen_variance
            + (pixel_weight * gamma)[:, None] * visual_drive)


def free_energy(s_p, mu, gamma, seen_pose, seen_variance, proprioceptive_variance, pixel_weight, visual_error):
    """F = sum (s_p - mu)^2/(2 Sigma_p) + gamma sum (x_v - mu)^2/(2 Sigma_x) + w gamma visual_error.

    The free energy whose gradient in mu is minus :func:`belief_rate` (the goal's pull aside).

    Parameters
    ----------
    s_p, mu, seen_pose, seen_variance : ndarray, (B, 2)
        As :func:`belief_rate`; mu is the step's start belief.
    gamma, proprioceptive_variance, pixel_weight, visual_error : ndarray, (B,)
        visual_error: the decoder's 1/2 e^T Sigma_v^-1 e (1).

    Returns
    -------
    ndarray, (B,)
        F, dimensionless.
    """
    return (((s_p - mu) ** 2).sum(axis=1) / (2.0 * proprioceptive_variance)
            + gamma * ((seen_pose - mu) ** 2 / (2.0 * seen_variance)).sum(axis=1) + pixel_weight * gamma * visual_error)


def stability_number(step, proprioceptive_variance, gamma, seen_variance, pixel_weight, visual_stiffness,
                     goal_stiffness):
    """dt * (1/Sigma_p + gamma / min Sigma_x + w gamma visual_stiffness + goal_stiffness): the stiffness of
    :func:`belief_rate` plus a goal's; explicit Euler is stable below 2.

    Parameters
    ----------
    step : float
        dt, s.
    proprioceptive_variance, gamma, pixel_weight, visual_stiffness, goal_stiffness : ndarray, (B,)
        Sigma_p (deg^2, read as 1/s), gamma (1), w (1), the pixel term's and the goal's stiffness (1/s).
    seen_variance : ndarray, (B, 2)
        Sigma_x, deg^2.

    Returns
    -------
    ndarray, (B,)
        Dimensionless.
    """
    return step * (1.0 / proprioceptive_variance + gamma * (1.0 / seen_variance).max(axis=1)
                   + pixel_weight * gamma * visual_stiffness + goal_stiffness)


class CausalBrain(PerceptualNoise, BeliefBrain):
    """The causal model's integrator: belief mu, action a, gamma (and its timing part), free energy.

    Parameters
    ----------
    name : str
        The instance name in a system.
    """

    finite_inputs = ("seen_pose", "seen_pose_variance", "visual_stiffness")  # the last always enters the guard

    def __init__(self, name="brain"):
        positive = dict(min=1e-12)
        # The parameters' starts are the model's settings (master/models/causal.toml; tests/test_model_defaults.py).
        super().__init__(name, [
            Variable("sync_sd", "parameter", start=0.2, unit="s", **positive,
                     description="sd of the true visuo-tactile delay under a common cause (paper eq. 8)"),
            Variable("async_density", "parameter", start=0.5, unit="1/s", **positive,
                     description="uniform density of the delay under separate causes (p2)"),
            Variable("pixel_weight", "parameter", start=0.0, unit="1", min=0.0,
                     description="weight of the paper's pixel term beside the body-space term (0: off)"),
            Variable("common_cause_prior", "parameter", start=0.28, unit="1", min=1e-6, max=1.0 - 1e-6,
                     description="population median of the common-cause chain's stationary probability"),
            Variable("switching_time", "parameter", start=20.0, unit="s", **positive,
                     description="population median of 1/(k_on + k_off), the common-cause state's memory"),
            Variable("timing_noise_sd", "parameter", start=0.1, unit="s", min=0.0,
                     description="population median sd of the perceived visuo-tactile delay's noise"),
            Variable("coupling_sd", "parameter", start=(1.0, 1.0), unit="deg", **JOINT,
                     description="population median spread of the seen from the felt pose under one cause"),
            Variable("workspace_mean", "parameter", start=(0.0, 0.0), unit="deg", **JOINT,
                     description="centre of the seen pose's density under separate causes"),
            Variable("workspace_sd", "parameter", start=(1.0, 1.0), unit="deg", **JOINT,
                     description="sd of the seen pose's density under separate causes"),
            Variable("participant_seed", "parameter", "Integer", start=0, min=0, unit="1",
                     description="seeds this trial's participant and its timing noise"),
            Variable("timing_noise_log_sd", "parameter", start=0.3, unit="1", min=0.0,
                     description="population: sd of log timing_noise_sd"),
            Variable("switching_log_sd", "parameter", start=0.3, unit="1", min=0.0,
                     description="population: sd of log switching_time"),
            Variable("coupling_log_sd", "parameter", start=0.2, unit="1", min=0.0,
                     description="population: sd of log coupling_sd"),
            Variable("prior_concentration", "parameter", start=20.0, unit="1", **positive,
                     description="population: the prior is Beta(prior k, (1 - prior) k)"),
            Variable("seen_pose", "input", start=(np.nan, np.nan), unit="deg", **JOINT,
                     description="x_v: the seen arm's joint angles, from the pose encoder"),
            Variable("seen_pose_variance", "input", start=(1.0, 1.0), unit="deg2", **JOINT,
                     description="Sigma_x: the pose encoder's calibrated variance of x_v"),
            *pixel_inputs("; read only when pixel_weight > 0"),
            Variable("gamma_timing", unit="1", min=0.0, max=1.0, **STATE,
                     description="the common-cause state's belief from the touches' timing alone"),
        ], gamma="belief in a common cause of the seen and the felt arm, over space and time")

    def publish_initial(self):
        """Each trial's participant drawn from its seed; mu = mu0, gamma = gamma_timing = the participant's
        prior, a = a_dot = 0, free energy NaN, no events seen."""
        v = self.values
        medians = {key: v[key] for key in ("common_cause_prior", "switching_time", "timing_noise_sd")}
        log_sds = {"timing_noise_sd": v["timing_noise_log_sd"], "switching_time": v["switching_log_sd"],
                   "coupling_scale": v["coupling_log_sd"]}
        self.participant, self._generators = participants(v["participant_seed"], medians, log_sds,
                                                          v["prior_concentration"])
        self.participant["coupling_sd"] = v["coupling_sd"] * self.participant.pop("coupling_scale")[:, None]
        super().publish_initial()
        v["gamma_timing"] = self.participant["common_cause_prior"].copy()
        v["gamma"] = v["gamma_timing"].copy()

    def check_parameters(self):
        """The shared parameters (:meth:`BeliefBrain.check_parameters`), then the coupling's and the
        workspace's sd positive."""
        super().check_parameters()
        for name in ("coupling_sd", "workspace_sd"):
            if not np.all(self.values[name] > 0):
                raise ComponentError(f"{self.name}.{name} must be positive, got {self.values[name].tolist()!r}")

    def rate(self, t, h, s_p, pair):
        """gamma from the touches' timing and the seen and felt pose (steps 1-2 of the module notes), mu_dot,
        the stiffness number and F at the step's start mu; see :meth:`BeliefBrain.rate`."""
        v, who = self.values, self.participant
        if np.any(v["seen_pose_variance"] <= 0):
            raise StepFailure("seen_pose_variance must be positive")
        pixels = v["pixel_weight"] > 0  # the pixel term's inputs are read only where it is on
        require_finite("visual_drive", np.where(pixels[:, None], v["visual_drive"], 0.0))
        require_finite("visual_error", np.where(pixels, v["visual_error"], 0.0))
        mu, variance = v["mu"], v["proprioceptive_variance"]

        # 1. the common-cause state: predict over the step, then the touches' timing where a pair is new.
        timing = hazard_predict(v["gamma_timing"], who["common_cause_prior"], who["switching_time"], h)
        streams = {}
        if pair.any():
            noise, streams = self._timing_noise(pair)
            delay = np.where(pair, v["visual_time"] - np.where(pair, v["tactile_time"], 0.0), 0.0)
            ratio = timing_likelihood_ratio(delay + who["timing_noise_sd"] * noise, v["sync_sd"],
                                            who["timing_noise_sd"], v["async_density"])
            timing = np.where(pair, posterior(timing, ratio), timing)
        # 2. the seen and the felt pose, counted once.
        spatial = spatial_likelihood_ratio(v["seen_pose"], v["seen_pose_variance"], s_p, variance,
                                           who["coupling_sd"], v["workspace_mean"], v["workspace_sd"])
        gamma = posterior(timing, spatial)

        number = stability_number(h, variance, gamma, v["seen_pose_variance"], v["pixel_weight"],
                                  v["visual_stiffness"], v["goal_stiffness"])
        drive = np.where(pixels[:, None], v["visual_drive"], 0.0)
        error = np.where(pixels, v["visual_error"], 0.0)
        mu_dot = add_goal_drive(belief_rate(s_p, mu, gamma, v["seen_pose"], v["seen_pose_variance"], variance,
                                            v["pixel_weight"], drive), v["goal_drive"])
        energy = free_energy(s_p, mu, gamma, v["seen_pose"], v["seen_pose_variance"], variance, v["pixel_weight"],
                             error)
        return BeliefRate(gamma, mu_dot, number, energy, {"gamma_timing": timing, "streams": streams})

    def stiffness_terms(self, i, rate):
        """The stability number's formula and values in trial ``i``, for the guard's message."""
        v = self.values
        pixels = " + pixel_weight * gamma * visual_stiffness" if v["pixel_weight"][i] else ""
        goal = " + goal_stiffness" if v["goal_stiffness"][i] else ""
        values = (f"Sigma_p = {v['proprioceptive_variance'][i]:g}, gamma = {rate.gamma[i]:.4g}, Sigma_x = "
                  f"{v['seen_pose_variance'][i].min():.4g}")
        if pixels:
            values += (f", pixel_weight = {v['pixel_weight'][i]:g}, visual_stiffness = "
                       f"{v['visual_stiffness'][i]:.4g} 1/s")
        if goal:
            values += f", goal_stiffness = {v['goal_stiffness'][i]:.4g} 1/s"
        return f"1/Sigma_p + gamma/Sigma_x{pixels}{goal}", values
