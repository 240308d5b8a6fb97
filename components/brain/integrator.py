"""The brain: the free-energy integrator of belief mu and action a (paper eqs. 6-7).

Each step, for each of the B trials, in the released agent's order (docs/design.md, "Brain"):

1. gamma from the events (eqs. 8-9, :mod:`rhi.components.brain.touch_timing`; with the
   extension over space there, ``spatial_sd`` finite, also from the seen and felt hands);
2. mu_dot = (s_p - mu)/Sigma_p + gamma * visual_drive [+ goal_drive, a reach goal's pull, unweighted by
   gamma; 0 unless the reach task connects it, docs/reach.md];  mu <- mu + dt * mu_dot  (:func:`belief_rate`);
3. a_dot = -(s_p - mu)/Sigma_p with the UPDATED mu  (:func:`~rhi.components.brain.action_law.action_rate`, eq. 7);
4. a <- clip(a + dt * (a_dot - a/tau), -limit, limit)  (:func:`~rhi.components.brain.action_law.action_update`, the
   action law).
Steps 2-4 after gamma are every brain's (:class:`~rhi.components.brain.base.BeliefBrain`); this model computes
gamma, mu_dot and the free energy (:meth:`Brain.rate`).

Step 3 uses mu after step 2, as the released agent does (it updates ``self.mu`` and then
computes ``a_dot`` from it): the action already pursues the new belief.

The action law (step 4). The action a is a commanded joint velocity (deg/s); the body's
velocity servo turns it into joint torques, and the held arm into a force at the hand.
- tau = inf is the paper's law as the released agent runs it: a <- clip(a + dt * a_dot),
  the action integrates a_dot (eq. 7). The held arm cannot move, so s_p stays put and any
  lasting belief-sense gap mu - s_p integrates until the clip: the final force then gives a
  direction, not a size (docs/results.md, "The action law"). ``tau = inf`` gives this law bit for bit
  (:func:`action_update` takes the paper's branch).
- tau finite (the default, 0.1 s) is a leaky integrator, the reflex arc of active inference
  (the action is driven by the proprioceptive prediction error) with a first-order
  response: a relaxes with time constant tau to a = -tau (s_p - mu)/Sigma_p, proportional
  to the belief-sense gap. The held arm's force then measures the gap: toward the rubber
  hand under synchronous touch, about none when the rubber hand overlays the real hand, as
  humans push (Lanillos et al. 2021, Sci Rep 11:22844; Asai 2015). Why 0.1 s: the time scale
  of the human stretch-reflex loop and of muscle force development (tens of ms to about a
  hundred), far shorter than the touch period and the rise of gamma, so the force follows the
  belief rather than its history. While the action stays off the clip, tau scales the force
  in proportion and leaves its signs and ratios as they are (docs/results.md, "The action law").
  Explicit Euler of the leak is stable while dt/tau < 2 (the step fails otherwise).
The paper's action measure (Fig. 3 d-f, the horizontal hand acceleration J a_dot) reads
a_dot of step 3, which does not depend on the law.

visual_drive = J^T (s_v - g(mu)) / Sigma_v comes from the decoder component, evaluated on
this brain's mu at the start of the step (Gauss-Seidel: decoder, then brain); the brain never
imports the decoder. Gradient flow units: the paper's mu_dot = -dF/dmu has an implicit unit
rate (1 deg^2/s per unit of F), so 1/Sigma_p reads as a rate in 1/s.

Free energy per step (output ``free_energy``, dimensionless):
    F = sum_j (s_p - mu)_j^2 / (2 Sigma_p) + gamma * visual_error,
with mu the belief the step started from (the one the decoder evaluated), gamma this step's
value, and visual_error the decoder's 1/2 e^T Sigma_v^-1 e (e = s_v - g(mu), Sigma_v per
pixel at the 256x256 reference), whose gradient is -visual_drive: so -dF/dmu is exactly the
mu_dot above. It is NaN at initialization (row 0 of a recording): s_p may not have arrived
yet, since the body steps after the brain.

Time of the events: under Gauss-Seidel the stimulus has already advanced to t + h when the
brain steps from t, so the decay of eq. 9 measures t + h minus the last tactile event time.

Guards (the step fails, the master stops the run; the shared step of :mod:`rhi.components.brain.base`):
explicit Euler of eq. 6 is stable only while dt * (1/Sigma_p + gamma * visual_stiffness) < 2,
visual_stiffness being the largest eigenvalue of J^T J / Sigma_v; the leaky action only while
dt/tau < 2; and every input and result must be finite (event times may be -inf: no event yet).
"""
from __future__ import annotations

import numpy as np

from .action_law import action_rate, action_update, add_goal_drive, euler_step
from .base import STABILITY_LIMIT, BeliefBrain, BeliefRate, trials_text
from .contract import JOINT, pixel_inputs
from .touch_timing import spatial_likelihood, update_gamma
from ..component import ComponentError, StepFailure
from ..variables import Variable

# The action law and the Euler step are action_law's, named here too: docs and master read them from this module.
__all__ = ["STABILITY_LIMIT", "Brain", "action_rate", "action_update", "belief_rate", "euler_step", "free_energy",
           "stability_number"]


def belief_rate(s_p, mu, gamma, visual_drive, proprioceptive_variance):
    """Paper eq. 6: mu_dot = (s_p - mu)/Sigma_p + gamma * J^T (s_v - g(mu))/Sigma_v.

    The visual term arrives as ``visual_drive`` from the decoder.

    Parameters
    ----------
    s_p, mu : ndarray, (B, 2)
        Sensed joint angles and belief, deg.
    gamma : ndarray, (B,)
        Belief in a common cause, 1.
    visual_drive : ndarray, (B, 2)
        J^T (s_v - g(mu))/Sigma_v, deg/s.
    proprioceptive_variance : ndarray, (B,)
        Sigma_p, deg^2.

    Returns
    -------
    ndarray, (B, 2)
        mu_dot, deg/s.
    """
    return (s_p - mu) / proprioceptive_variance[:, None] + gamma[:, None] * visual_drive


def free_energy(s_p, mu, gamma, visual_error, proprioceptive_variance):
    """F = sum_j (s_p - mu)_j^2 / (2 Sigma_p) + gamma * visual_error (module notes; -dF/dmu is eq. 6).

    Parameters
    ----------
    s_p, mu : ndarray, (B, 2)
        Sensed joint angles and the step's start belief, deg.
    gamma, visual_error, proprioceptive_variance : ndarray, (B,)
        gamma (1), the decoder's 1/2 e^T Sigma_v^-1 e (1), Sigma_p (deg^2).

    Returns
    -------
    ndarray, (B,)
        F, dimensionless.
    """
    return ((s_p - mu) ** 2).sum(axis=1) / (2.0 * proprioceptive_variance) + gamma * visual_error


def stability_number(step, proprioceptive_variance, gamma, visual_stiffness):
    """dt * (1/Sigma_p + gamma * visual_stiffness): explicit Euler of eq. 6 is stable below 2.

    Parameters
    ----------
    step : float
        dt, s.
    proprioceptive_variance, gamma, visual_stiffness : ndarray, (B,)
        Sigma_p (deg^2, read as 1/s), gamma (1), the largest eigenvalue of J^T J / Sigma_v (1/s).

    Returns
    -------
    ndarray, (B,)
        Dimensionless.
    """
    return step * (1.0 / proprioceptive_variance + gamma * visual_stiffness)


class Brain(BeliefBrain):
    """The paper's free-energy integrator: belief mu, action a, gamma and free energy for B trials.

    Parameters
    ----------
    name : str
        The instance name in a system.
    """

    finite_inputs = ("visual_drive", "visual_error", "visual_stiffness")
    stiffness_remedy = "a larger visual_variance"

    def __init__(self, name="brain"):
        super().__init__(name, [
            "proprioceptive_variance",
            Variable("gamma0", "parameter", start=0.01, unit="1", min=0.0, max=1.0,
                     description="initial gamma and its floor (the prior of a common cause)"),
            "mu0",
            Variable("sync_sd", "parameter", start=0.2, unit="s", min=0.0,
                     description="sd of the visuo-tactile delay under a common cause"),
            Variable("async_density", "parameter", start=0.5, unit="1/s", min=0.0,
                     description="uniform density of the delay under separate causes (p2)"),
            Variable("decay_rate", "parameter", start=1.0 / 80.0, unit="1/s3", min=0.0,
                     description="r_decay; gamma *= exp(-(t - t_t)^2 * dt * r_decay) between events"),
            "action_limit",
            Variable("spatial_sd", "parameter", start=np.inf, unit="m", min=0.0,
                     description="extension: sd of the seen-felt hand distance under a common cause (causal "
                                 "inference over space); inf = the paper's model, gamma ignores space"),
            "action_time_constant", "q_shoulder", "q_elbow",
            *pixel_inputs(),
            "goal_drive", "goal_error", "goal_stiffness",
            Variable("seen_hand", "input", start=(np.nan, np.nan), unit="m", **JOINT,
                     description="the seen (rubber) hand (x, y); read only when spatial_sd is finite"),
            Variable("hand_x", "input", start=np.nan, unit="m",
                     description="the felt hand: x of the sensed arm's hand; read only when spatial_sd is finite"),
            Variable("hand_y", "input", start=np.nan, unit="m",
                     description="the felt hand: y of the sensed arm's hand; read only when spatial_sd is finite"),
            "visual_time", "tactile_time", "mu", "u_shoulder", "u_elbow", "action_rate", "gamma", "free_energy",
        ], gamma="belief that seen and felt touch share a cause; weights vision",
            free_energy="sum (s_p - mu)^2 / (2 Sigma_p) + gamma * visual_error, at the step's start mu")

    def publish_initial(self):
        """mu = mu0, gamma = gamma0, a = a_dot = 0, free energy NaN, no events seen: the decoder,
        earlier in the step order, reads mu0 in initialization mode."""
        super().publish_initial()
        self.values["gamma"] = self.values["gamma0"].copy()

    def check_parameters(self):
        """The shared parameters (:meth:`BeliefBrain.check_parameters`), then the events' law positive and
        finite and ``spatial_sd`` positive (inf: the paper's model)."""
        super().check_parameters()
        self.require_positive_finite("sync_sd", "async_density")
        spatial = self.values["spatial_sd"]
        if np.any(~(spatial > 0)):
            raise ComponentError(f"{self.name}.spatial_sd must be positive (inf: the paper's model), "
                                 f"got {float(spatial[~(spatial > 0)][0])!r}")

    def _hands(self):
        """(seen, felt) hands as (B, 2) m; checked finite only in trials that read them (spatial_sd finite)."""
        v = self.values
        seen, felt = v["seen_hand"], np.stack([v["hand_x"], v["hand_y"]], axis=1)
        used = np.isfinite(v["spatial_sd"])
        for name, value in (("seen_hand", seen), ("hand_x", felt[:, 0]), ("hand_y", felt[:, 1])):
            bad = used & ~np.isfinite(value.reshape(len(value), -1)).all(axis=1)
            if bad.any():
                first = np.ravel(value[np.flatnonzero(bad)[0]])
                first = first[~np.isfinite(first)][0]
                raise StepFailure(f"{name} is not finite ({first}) in {trials_text(bad)} (brain.spatial_sd is "
                                  f"finite, so the seen and the felt hand must be connected)")
        return seen, felt

    def initialize(self):
        """mu = mu0, a = a_dot = 0, gamma = gamma0, free energy NaN; the inputs but s_p checked finite.

        F is the free energy each step descends, so it exists from the first step on: at
        initialization s_p may not have arrived (the body comes after the brain in the agreed
        order, and the brain would see its start value), so row 0 of a recorded F is NaN.
        """
        super().initialize()
        self.check_inputs(proprioception=False)

    def rate(self, t, h, s_p, pair):
        """gamma (eqs. 8-9, Bayes once a new pair of events is seen), mu_dot (eq. 6 plus a goal's pull), the
        stiffness number and F at the step's start mu (module notes); see :meth:`BeliefBrain.rate`."""
        v = self.values
        mu, variance = v["mu"], v["proprioceptive_variance"]
        gamma = self.common_cause(t, h, pair)
        number = stability_number(h, variance, gamma, v["visual_stiffness"]) + h * v["goal_stiffness"]
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is named after the step, by the base
            mu_dot = add_goal_drive(belief_rate(s_p, mu, gamma, v["visual_drive"], variance), v["goal_drive"])
            energy = free_energy(s_p, mu, gamma, v["visual_error"], variance)
            if np.any(v["goal_error"]):
                energy = energy + v["goal_error"]
        return BeliefRate(gamma, mu_dot, number, energy)

    def common_cause(self, t, h, pair):
        """gamma (B,): the belief in a common cause after this step's events (eqs. 8-9, and the spatial
        extension when ``spatial_sd`` is finite). A model of one's own may override it (examples/my_model.py).

        Parameters
        ----------
        t, h : float
            The step's start time and size, s.
        pair : numpy.ndarray
            (B,) bool: whether a new pair of a visual and a tactile event was seen in each trial.
        """
        v = self.values
        spatial = spatial_likelihood(*self._hands(), v["spatial_sd"])
        return update_gamma(v["gamma"], pair, v["visual_time"], v["tactile_time"], t + h, h, v["gamma0"],
                            v["sync_sd"], v["async_density"], v["decay_rate"], spatial)

    def stiffness_terms(self, i, rate):
        """The stability number's formula and values in trial ``i``, for the guard's message."""
        v = self.values
        goal = " + goal_stiffness" if v["goal_stiffness"][i] else ""
        return (f"1/Sigma_p + gamma * visual_stiffness{goal}",
                f"Sigma_p = {v['proprioceptive_variance'][i]:g}, gamma = {rate.gamma[i]:.4g}, visual_stiffness = "
                f"{v['visual_stiffness'][i]:.4g} 1/s")
