"""The ownership model's brain: ownership gamma from the touches' timing and the seen hand's place; the drift as a
slow realignment b driven by a coupling rho that needs no touch.

Each step, for each of the B trials (docs/model.md, "The ownership model"; each equation one function of
:mod:`rhi.components.brain.ownership_inference`, the beliefs, or :mod:`rhi.components.brain.realignment`, the drift):

1. a hand is seen only where the scene says one is in view (``arm_visible``, :func:`seen_hand`); the seen
   hand's place (the pose encoder's reading against the sensed angles, by the body schema) is evidence about one
   cause, counted once (:func:`spatial_log_likelihood_ratio`);
2. the timing belief gamma_t is a two-state chain relaxing to its prior gamma0 at the switching rate
   (:func:`~rhi.components.brain.body_inference.hazard_predict`); at a new visuo-tactile pair of a seen hand it adds
   the perceived asynchrony's log ratio in ownership's window (:func:`asynchrony_log_likelihood_ratio`, the
   delay plus this trial's perceptual noise) by Bayes' rule; ownership gamma is gamma_t with the place
   (:func:`ownership_belief`), so it depends on the seen hand's place before any touch; its onset is the first
   time it reaches 1/2;
3. the counter-evidence C sums the same touches' log ratios in the coupling's wider window and leaks
   (:func:`relaxation_step` toward 0); the coupling rho is its prior with the place and C
   (:func:`coupling_belief`);
4. the proprioceptive variance grows while the arm rests and recovers as it moves (:func:`felt_variance_step`);
   the seen hand's weight w follows it (:func:`visual_weight`); the realignment b relaxes at rate k toward
   w rho (x_v - s_p) while a hand is seen, and holds while none is (:func:`relaxation_step`);
5. mu_dot = (s_p + b - mu)/Sigma_p(t): the belief (the perceived arm) follows the realigned proprioception, so
   the drift is b as it builds; the action and the guards are every brain's
   (:class:`~rhi.components.brain.base.BeliefBrain`: a_dot = -(s_p - mu)/Sigma_p0, the belief-sense gap).

A reach goal's pull (input ``goal_drive``) is added to mu_dot as in the other brains. The brain reads no
position from the simulator: the seen arm reaches it only as the pose encoder's reading of the camera's image,
the felt arm as the sensed joint angles. The perceptual noise of each trial comes from its own generator,
seeded by ``participant_seed``.
"""
from __future__ import annotations

import numpy as np

from .action_law import add_goal_drive
from .base import BeliefBrain, BeliefRate, PerceptualNoise
from .contract import JOINT, STATE
from .body_inference import hazard_predict, posterior
from .ownership_inference import asynchrony_log_likelihood_ratio, coupling_belief, hand_separation, \
    ownership_belief, ownership_onset, relaxation_step, seen_hand, spatial_log_likelihood_ratio
from .realignment import belief_rate, felt_variance_step, free_energy, realignment_target, visual_weight
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

    finite_inputs = ("seen_pose", "arm_visible")

    def __init__(self, name="brain"):
        positive = dict(min=1e-12)
        probability = dict(min=1e-6, max=1.0 - 1e-6)
        # The parameters' starts are the model's settings (master/models/ownership.toml; tests/test_model_defaults.py).
        super().__init__(name, [
            Variable("ownership_prior", "parameter", start=0.000227, unit="1", **probability,
                     description="gamma_t's prior and the stationary probability of its chain (the paper's gamma0's role)"),
            Variable("coupling_prior", "parameter", start=0.869, unit="1", **probability,
                     description="rho's prior: a seen hand is coupled to the felt one before any touch"),
            Variable("timing_sd", "parameter", start=0.2, unit="s", **positive,
                     description="sigma_t, sd of the perceived visuo-tactile asynchrony: ownership's window"),
            Variable("coupling_window_sd", "parameter", start=0.492, unit="s", **positive,
                     description="sigma_c, the coupling's (visuo-proprioceptive) window: the sd of a touch's "
                                 "asynchrony under unity"),
            Variable("counter_evidence_leak", "parameter", start=0.145, unit="1/s", min=0.0,
                     description="kappa, the rate at which the touches' accumulated evidence about unity is "
                                 "forgotten"),
            Variable("stroke_period", "parameter", start=2.0, unit="s", **positive,
                     description="T: the asynchrony under two causes is uniform over one period (density 1/T)"),
            Variable("peripersonal_sd", "parameter", start=0.127, unit="m", **positive,
                     description="sigma_s: spread of a seen touch about the felt one under one cause, per axis"),
            Variable("upper_arm_length", "parameter", start=0.3595, unit="m", **positive,
                     description="the body schema's upper arm (shoulder to elbow)"),
            Variable("forearm_length", "parameter", start=0.3694, unit="m", **positive,
                     description="the body schema's forearm (elbow to hand); the reach L is the two summed"),
            Variable("switching_rate", "parameter", start=0.255, unit="1/s", min=0.0,
                     description="lambda = k_on + k_off of ownership's chain (0: evidence kept for good)"),
            Variable("realignment_weight", "parameter", start=0.39, unit="1", min=1e-6, max=1.0,
                     description="w0: the fraction of the way a seen arm pulls the felt one, proprioception rested"),
            Variable("proprioceptive_fading_rate", "parameter", start=0.00909, unit="1/s", min=0.0,
                     description="phi: Sigma_p grows by phi Sigma_p0 per second while the arm rests (0: constant)"),
            Variable("realignment_rate", "parameter", start=0.243, unit="1/s", min=0.0,
                     description="k: the rate of the realignment b toward w rho (x_v - s_p)"),
            Variable("participant_seed", "parameter", "Integer", start=0, min=0, unit="1",
                     description="seeds this trial's perceptual timing noise"),
            Variable("seen_pose", "input", start=(np.nan, np.nan), unit="deg", **JOINT,
                     description="x_v: the seen arm's joint angles, from the pose encoder"),
            Variable("arm_visible", "input", start=1.0, unit="1",
                     description="the scene's declaration: 1 while a rubber arm is in view, 0 while none is"),
            Variable("timing_belief", unit="1", min=0.0, max=1.0, **STATE,
                     description="gamma_t: the belief in one cause from the touches' timing alone (a two-state chain)"),
            Variable("coupling", unit="1", min=0.0, max=1.0, **STATE,
                     description="rho: the belief that the seen arm lies where the felt one is"),
            Variable("counter_evidence", unit="1", **STATE,
                     description="C: the touches' accumulated evidence about visuo-proprioceptive unity, nats"),
            Variable("realignment", unit="deg", **JOINT, **STATE,
                     description="b: the slow realignment of the felt arm toward the seen one"),
            Variable("felt_variance", unit="deg2", **STATE,
                     description="Sigma_p(t): the proprioceptive variance, rising at rest, recovering with movement"),
            Variable("ownership_onset", unit="s", **STATE,
                     description="the first time gamma reached 1/2 (NaN: not yet)"),
        ], gamma="ownership: the belief that the seen arm is one's own, from the touches' timing and the seen "
                 "hand's place")

    def publish_initial(self):
        """mu = mu0, a = a_dot = 0, gamma and rho at their priors, b = 0, no onset, no events seen; each
        trial's noise generator from its seed."""
        v = self.values
        super().publish_initial()
        self._generators = [np.random.default_rng([int(seed), NOISE_STREAM]) for seed in v["participant_seed"]]
        v["gamma"] = v["ownership_prior"].copy()
        v["counter_evidence"] = np.zeros(self.batch_size)
        v["timing_belief"] = v["ownership_prior"].copy()
        v["felt_variance"] = v["proprioceptive_variance"].copy()
        self._sensed = None  # s_p of the previous step: the movement over a step
        v["coupling"] = v["coupling_prior"].copy()  # until the first step reads the seen hand's place
        v["realignment"] = np.zeros((self.batch_size, 2))
        v["ownership_onset"] = np.full(self.batch_size, np.nan)

    def check_parameters(self):
        """The shared parameters (:meth:`BeliefBrain.check_parameters`), then the model's rates and times
        positive or zero and finite."""
        super().check_parameters()
        self.require_positive_finite("timing_sd", "coupling_window_sd", "stroke_period", "peripersonal_sd",
                                     "upper_arm_length", "forearm_length")
        for name in ("switching_rate", "realignment_rate", "counter_evidence_leak", "proprioceptive_fading_rate"):
            bad = self.values[name][~((self.values[name] >= 0) & np.isfinite(self.values[name]))]
            if bad.size:
                raise ComponentError(f"{self.name}.{name} must be >= 0 and finite, got {float(bad[0])!r}")

    def rate(self, t, h, s_p, pair):
        """The beliefs, the onset, b over the step, mu_dot, the stiffness number and F (the module notes'
        steps 1-4); see :meth:`BeliefBrain.rate`."""
        v = self.values
        with np.errstate(divide="ignore"):  # rate 0: switching time inf, no relaxation
            switching_time = 1.0 / v["switching_rate"]
        timing = hazard_predict(v["timing_belief"], v["ownership_prior"], switching_time, h)
        counter = relaxation_step(v["counter_evidence"], 0.0, v["counter_evidence_leak"], h)  # leaks toward 0
        streams, seen = {}, seen_hand(v["arm_visible"])
        upper, forearm = v["upper_arm_length"], v["forearm_length"]
        place = seen * spatial_log_likelihood_ratio(hand_separation(v["seen_pose"], s_p, upper, forearm),
                                                    v["peripersonal_sd"], upper + forearm)
        pair = pair & (seen > 0)  # the ball touching no seen hand is no visuo-tactile pair
        if pair.any():
            noise, streams = self._timing_noise(pair)
            delay = np.where(pair, v["visual_time"] - np.where(pair, v["tactile_time"], 0.0), 0.0)
            perceived = delay + v["timing_sd"] * noise
            ownership_evidence = asynchrony_log_likelihood_ratio(perceived, v["timing_sd"], v["stroke_period"])
            timing = np.where(pair, posterior(timing, np.exp(np.where(pair, ownership_evidence, 0.0))), timing)
            unity_evidence = asynchrony_log_likelihood_ratio(perceived, v["coupling_window_sd"], v["stroke_period"])
            counter = counter + np.where(pair, unity_evidence, 0.0)
        gamma = ownership_belief(timing, place)
        coupling = coupling_belief(v["coupling_prior"], place, counter)
        onset = ownership_onset(v["ownership_onset"], gamma, t + h)
        moved = np.zeros(self.batch_size) if self._sensed is None else np.abs(s_p - self._sensed).sum(axis=1)
        variance = v["felt_variance"]  # this step's Sigma_p; the next is stepped below
        weight = visual_weight(variance, v["proprioceptive_variance"], v["realignment_weight"])
        target = realignment_target(v["seen_pose"], s_p, weight, coupling, seen)
        realignment = relaxation_step(v["realignment"], target, v["realignment_rate"] * seen, h)
        felt = felt_variance_step(variance, v["proprioceptive_variance"], v["proprioceptive_fading_rate"], moved, h)

        mu = v["mu"]
        mu_dot = add_goal_drive(belief_rate(s_p, v["realignment"], mu, variance), v["goal_drive"])
        number = h * (1.0 / variance + v["goal_stiffness"])
        energy = free_energy(s_p, v["realignment"], mu, variance)
        return BeliefRate(gamma, mu_dot, number, energy, {"timing_belief": timing, "coupling": coupling,
                                                          "counter_evidence": counter,
                                                          "felt_variance": felt, "sensed": s_p.copy(),
                                                          "realignment": realignment,
                                                          "ownership_onset": onset, "streams": streams})

    def commit(self, state):
        """The step's state, keeping the step's sensed angles (the next step's movement is measured from them)."""
        state = dict(state)
        self._sensed = state.pop("sensed")
        super().commit(state)

    def stiffness_terms(self, i, rate):
        """The stability number's formula and values in trial ``i``, for the guard's message."""
        v = self.values
        goal = " + goal_stiffness" if v["goal_stiffness"][i] else ""
        values = f"Sigma_p = {v['felt_variance'][i]:g}, gamma = {rate.gamma[i]:.4g} (not in the number)"
        if goal:
            values += f", goal_stiffness = {v['goal_stiffness'][i]:.4g} 1/s"
        return f"1/Sigma_p{goal}", values
