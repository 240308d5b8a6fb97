"""The ownership model's brain: ownership gamma from accumulated timing evidence, drift as a slow realignment b.

Each step, for each of the B trials (docs/model.md, "The ownership model"; the equations in
:mod:`rhi.components.brain.ownership_inference`):

1. ownership gamma and the coupling rho, two common-cause beliefs about the seen and the felt arm, are
   predicted over the step as two-state chains relaxing to their priors at the switching rate
   (:func:`~rhi.components.brain.body_inference.hazard_predict`); at a new visuo-tactile pair both add the same
   touch's evidence: the log likelihood ratio of the perceived asynchrony
   (:func:`~rhi.components.brain.ownership_inference.asynchrony_log_likelihood_ratio`; the delay plus this
   trial's perceptual noise) plus that of the distance between the seen and the felt hand
   (:func:`~rhi.components.brain.ownership_inference.spatial_log_likelihood_ratio`), by Bayes' rule
   (:func:`~rhi.components.brain.body_inference.posterior`). They differ
   only in their priors: ownership starts from the paper's gamma0 and needs evidence; the coupling starts high
   and needs none, but asynchronous touches take it away;
2. the ownership onset: the first time gamma reaches 1/2;
3. the realignment b relaxes at rate k toward w rho (x_v - s_p), exactly over the step;
4. mu_dot = (s_p + b - mu)/Sigma_p: the belief (the perceived arm) follows the realigned proprioception, so
   the drift is b as it builds; the action and the guards are every brain's
   (:class:`~rhi.components.brain.base.BeliefBrain`: a_dot = -(s_p - mu)/Sigma_p, the belief-sense gap).

A reach goal's pull (input ``goal_drive``) is added to mu_dot as in the other brains. The brain reads no
position from the simulator: the seen arm reaches it only as the pose encoder's reading of the camera's image,
the felt arm as the sensed joint angles. The perceptual noise of each trial comes from its own generator,
seeded by ``participant_seed``.
"""
from __future__ import annotations

import numpy as np

from .base import JOINT, STATE, BeliefBrain, PerceptualNoise, BeliefRate, add_goal_drive
from .body_inference import hazard_predict, posterior
from .ownership_inference import asynchrony_log_likelihood_ratio, belief_rate, free_energy, \
    hand_separation, ownership_onset, realignment_step, realignment_target, spatial_log_likelihood_ratio
from ..component import ComponentError
from ..variables import Variable

NOISE_STREAM = 2  # the trial's generator is numpy's default_rng([participant_seed, NOISE_STREAM])


class OwnershipBrain(PerceptualNoise, BeliefBrain):
    """Belief mu, action a, ownership gamma, coupling rho, realignment b and the ownership onset.

    Parameters
    ----------
    name : str
        The instance name in a system.
    """

    finite_inputs = ("seen_pose",)

    def __init__(self, name="brain"):
        positive = dict(min=1e-12)
        probability = dict(min=1e-6, max=1.0 - 1e-6)
        super().__init__(name, [
            Variable("ownership_prior", "parameter", start=0.01, unit="1", **probability,
                     description="gamma's prior and the stationary probability of its chain (the paper's gamma0)"),
            Variable("coupling_prior", "parameter", start=0.73, unit="1", **probability,
                     description="rho's prior: a seen hand is coupled to the felt one before any touch"),
            Variable("timing_sd", "parameter", start=0.089, unit="s", **positive,
                     description="sigma_t, sd of the perceived visuo-tactile asynchrony"),
            Variable("stroke_period", "parameter", start=2.0, unit="s", **positive,
                     description="T: the asynchrony under two causes is uniform over one period (density 1/T)"),
            Variable("peripersonal_sd", "parameter", start=0.127, unit="m", **positive,
                     description="sigma_s: spread of a seen touch about the felt one under one cause, per axis"),
            Variable("upper_arm_length", "parameter", start=0.3595, unit="m", **positive,
                     description="the body schema's upper arm (shoulder to elbow)"),
            Variable("forearm_length", "parameter", start=0.3694, unit="m", **positive,
                     description="the body schema's forearm (elbow to hand); the reach L is the two summed"),
            Variable("switching_rate", "parameter", start=0.0, unit="1/s", min=0.0,
                     description="lambda = k_on + k_off of the common-cause chains (0: evidence kept for good)"),
            Variable("realignment_weight", "parameter", start=0.39, unit="1", min=0.0, max=1.0,
                     description="w: the fraction of the way a seen arm pulls the felt one"),
            Variable("realignment_rate", "parameter", start=0.0, unit="1/s", min=0.0,
                     description="k: the rate of the realignment b toward w rho (x_v - s_p)"),
            Variable("participant_seed", "parameter", "Integer", start=0, min=0, unit="1",
                     description="seeds this trial's perceptual timing noise"),
            Variable("seen_pose", "input", start=(np.nan, np.nan), unit="deg", **JOINT,
                     description="x_v: the seen arm's joint angles, from the pose encoder"),
            Variable("coupling", unit="1", min=0.0, max=1.0, **STATE,
                     description="rho: the belief that the seen arm lies where the felt one is"),
            Variable("realignment", unit="deg", **JOINT, **STATE,
                     description="b: the slow realignment of the felt arm toward the seen one"),
            Variable("ownership_onset", unit="s", **STATE,
                     description="the first time gamma reached 1/2 (NaN: not yet)"),
        ], gamma="ownership: the belief that the seen arm is one's own, from the touches' timing")

    def publish_initial(self):
        """mu = mu0, a = a_dot = 0, gamma and rho at their priors, b = 0, no onset, no events seen; each
        trial's noise generator from its seed."""
        v = self.values
        super().publish_initial()
        self._generators = [np.random.default_rng([int(seed), NOISE_STREAM]) for seed in v["participant_seed"]]
        v["gamma"] = v["ownership_prior"].copy()
        v["coupling"] = v["coupling_prior"].copy()
        v["realignment"] = np.zeros((self.batch_size, 2))
        v["ownership_onset"] = np.full(self.batch_size, np.nan)

    def check_parameters(self):
        """The shared parameters (:meth:`BeliefBrain.check_parameters`), then the model's rates and times
        positive or zero and finite."""
        super().check_parameters()
        self.require_positive_finite("timing_sd", "stroke_period", "peripersonal_sd", "upper_arm_length",
                                     "forearm_length")
        for name in ("switching_rate", "realignment_rate"):
            bad = self.values[name][~((self.values[name] >= 0) & np.isfinite(self.values[name]))]
            if bad.size:
                raise ComponentError(f"{self.name}.{name} must be >= 0 and finite, got {float(bad[0])!r}")

    def rate(self, t, h, s_p, pair):
        """The beliefs, the onset, b over the step, mu_dot, the stiffness number and F (the module notes'
        steps 1-4); see :meth:`BeliefBrain.rate`."""
        v = self.values
        with np.errstate(divide="ignore"):  # rate 0: switching time inf, no relaxation
            switching_time = 1.0 / v["switching_rate"]
        gamma = hazard_predict(v["gamma"], v["ownership_prior"], switching_time, h)
        coupling = hazard_predict(v["coupling"], v["coupling_prior"], switching_time, h)
        streams = {}
        if pair.any():
            noise, streams = self._timing_noise(pair)
            delay = np.where(pair, v["visual_time"] - np.where(pair, v["tactile_time"], 0.0), 0.0)
            evidence = asynchrony_log_likelihood_ratio(delay + v["timing_sd"] * noise, v["timing_sd"],
                                                       v["stroke_period"])
            upper, forearm = v["upper_arm_length"], v["forearm_length"]
            evidence = evidence + spatial_log_likelihood_ratio(
                hand_separation(v["seen_pose"], s_p, upper, forearm), v["peripersonal_sd"], upper + forearm)
            ratio = np.exp(np.where(pair, evidence, 0.0))
            gamma = np.where(pair, posterior(gamma, ratio), gamma)
            coupling = np.where(pair, posterior(coupling, ratio), coupling)
        onset = ownership_onset(v["ownership_onset"], gamma, t + h)
        target = realignment_target(v["seen_pose"], s_p, v["realignment_weight"], coupling)
        realignment = realignment_step(v["realignment"], target, v["realignment_rate"], h)

        variance, mu = v["proprioceptive_variance"], v["mu"]
        mu_dot = add_goal_drive(belief_rate(s_p, v["realignment"], mu, variance), v["goal_drive"])
        number = h * (1.0 / variance + v["goal_stiffness"])
        energy = free_energy(s_p, v["realignment"], mu, variance)
        return BeliefRate(gamma, mu_dot, number, energy, {"coupling": coupling, "realignment": realignment,
                                                          "ownership_onset": onset, "streams": streams})

    def stiffness_terms(self, i, rate):
        """The stability number's formula and values in trial ``i``, for the guard's message."""
        v = self.values
        goal = " + goal_stiffness" if v["goal_stiffness"][i] else ""
        values = f"Sigma_p = {v['proprioceptive_variance'][i]:g}, gamma = {rate.gamma[i]:.4g} (not in the number)"
        if goal:
            values += f", goal_stiffness = {v['goal_stiffness'][i]:.4g} 1/s"
        return f"1/Sigma_p{goal}", values
