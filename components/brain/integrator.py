"""The brain: the free-energy integrator of belief mu and action a (paper eqs. 6-7).

Each step, for each of the B trials, in the released agent's order (docs/design.md, "Brain"):

1. gamma from the events (eqs. 8-9, :mod:`components.brain.causal_inference`; with the
   extension over space there, ``spatial_sd`` finite, also from the seen and felt hands);
2. mu_dot = (s_p - mu)/Sigma_p + gamma * visual_drive [+ goal_drive, a reach goal's pull, unweighted by
   gamma; 0 unless the reach task connects it, docs/reach.md];  mu <- mu + dt * mu_dot  (:func:`belief_rate`);
3. a_dot = -(s_p - mu)/Sigma_p with the UPDATED mu  (:func:`action_rate`, eq. 7);
4. a <- clip(a + dt * (a_dot - a/tau), -limit, limit)  (:func:`action_update`, the action law).

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

Guards (the step fails, the master stops the run): explicit Euler of eq. 6 is stable only
while dt * (1/Sigma_p + gamma * visual_stiffness) < 2, visual_stiffness being the largest
eigenvalue of J^T J / Sigma_v; the leaky action only while dt/tau < 2; and every input and
result must be finite (event times may be -inf: no event yet).
"""
from __future__ import annotations

import numpy as np

from components.brain.causal_inference import observe_events, spatial_likelihood, update_gamma
from components.brain.goal import goal_inputs
from components.component import Component, ComponentError, StepFailure
from components.variables import Variable

STABILITY_LIMIT = 2.0  # explicit Euler on a linear decay of rate k is stable iff dt * k < 2


def belief_rate(s_p, mu, gamma, visual_drive, proprioceptive_variance):
    """Paper eq. 6: mu_dot = (s_p - mu)/Sigma_p + gamma * J^T (s_v - g(mu))/Sigma_v.

    The visual term arrives as ``visual_drive`` from the decoder. s_p, mu, visual_drive:
    (B, 2) deg and deg/s; gamma, proprioceptive_variance: (B,). Returns (B, 2) deg/s.
    """
    return (s_p - mu) / proprioceptive_variance[:, None] + gamma[:, None] * visual_drive


def action_rate(s_p, mu, proprioceptive_variance):
    """Paper eq. 7 as docs/design.md and the released agent write it: a_dot = -(s_p - mu)/Sigma_p.

    The paper's extra factor dt (from ds/da = dt) is left out, as in the released agent.
    """
    return -(s_p - mu) / proprioceptive_variance[:, None]


def action_update(action, a_dot, action_time_constant, action_limit, h):
    """The action law: a <- clip(a + h * (a_dot - a/tau), -limit, limit); (B, 2) deg/s.

    tau = ``action_time_constant`` (s, (B,)): inf is the paper's law a <- clip(a + h * a_dot)
    (computed as written, so bit for bit the released agent's), a finite tau the leaky
    integrator whose fixed point is a = tau * a_dot (module notes). action, a_dot: (B, 2);
    action_limit: (B,).
    """
    tau, limit = action_time_constant[:, None], action_limit[:, None]
    paper = np.isinf(tau)
    leaky = action + h * (a_dot - action / np.where(paper, 1.0, tau))
    return np.clip(np.where(paper, action + h * a_dot, leaky), -limit, limit)


def euler_step(mu, action, s_p, gamma, visual_drive, proprioceptive_variance, action_limit, h,
               action_time_constant, goal_drive=None):
    """One explicit Euler step of eqs. 6 and 7 in the released agent's order; returns (new_mu, a_dot, new_action).

    mu <- mu + h * mu_dot (:func:`belief_rate`, plus ``goal_drive`` when given); a_dot from the UPDATED mu
    (:func:`action_rate`); the action by the action law (:func:`action_update`). mu, action, s_p, visual_drive,
    goal_drive: (B, 2); gamma, proprioceptive_variance, action_limit, action_time_constant: (B,).

    goal_drive: a reach goal's pull on the belief, added to mu_dot unweighted by gamma, as the released agent
    adds its attractor term (``FepAgent.active_inference_step``: mu_dot = dF_dmu_vis + dF_dmu_attr +
    proprioception; the term itself: the goal decoder's drive or ``components.brain.goal``).
    """
    rate = belief_rate(s_p, mu, gamma, visual_drive, proprioceptive_variance)
    if goal_drive is not None and np.any(goal_drive):
        rate = rate + goal_drive
    new_mu = mu + h * rate
    a_dot = action_rate(s_p, new_mu, proprioceptive_variance)
    return new_mu, a_dot, action_update(action, a_dot, action_time_constant, action_limit, h)


def free_energy(s_p, mu, gamma, visual_error, proprioceptive_variance):
    """F = sum_j (s_p - mu)_j^2 / (2 Sigma_p) + gamma * visual_error, per trial (B,)."""
    return ((s_p - mu) ** 2).sum(axis=1) / (2.0 * proprioceptive_variance) + gamma * visual_error


def stability_number(step, proprioceptive_variance, gamma, visual_stiffness):
    """dt * (1/Sigma_p + gamma * visual_stiffness): explicit Euler of eq. 6 is stable below 2."""
    return step * (1.0 / proprioceptive_variance + gamma * visual_stiffness)


def _trials(mask) -> str:
    indices = np.flatnonzero(mask)
    shown = ", ".join(map(str, indices[:5])) + (", ..." if len(indices) > 5 else "")
    return f"trial{'s' if len(indices) > 1 else ''} {shown}"


def _require_finite(name, value, allow_minus_inf=False):
    """StepFailure naming the variable, the first bad value and the trials, if any value is bad."""
    value = np.asarray(value)
    bad = np.isnan(value) | (value == np.inf) if allow_minus_inf else ~np.isfinite(value)
    per_trial = bad.reshape(len(value), -1).any(axis=1)
    if per_trial.any():
        raise StepFailure(f"{name} is not finite ({value[bad].flat[0]}) in {_trials(per_trial)}")


class Brain(Component):
    """Free-energy integrator: belief mu, action a, gamma and free energy for B trials."""

    def __init__(self, name="brain"):
        joint = dict(type="Array", shape=(2,))
        state = dict(causality="output", depends_on=())
        super().__init__(name, [
            Variable("proprioceptive_variance", "parameter", start=1.0, unit="deg2", min=0.0,
                     description="Sigma_p, proprioceptive variance (1/Sigma_p is the belief's relaxation rate, 1/s)"),
            Variable("gamma0", "parameter", start=0.01, unit="1", min=0.0, max=1.0,
                     description="initial gamma and its floor (the prior of a common cause)"),
            Variable("mu0", "parameter", start=(0.0, 0.0), unit="deg", **joint,
                     description="initial belief (shoulder, elbow); the master sets the rest pose"),
            Variable("sync_sd", "parameter", start=0.2, unit="s", min=0.0,
                     description="sd of the visuo-tactile delay under a common cause"),
            Variable("async_density", "parameter", start=0.5, unit="1/s", min=0.0,
                     description="uniform density of the delay under separate causes (p2)"),
            Variable("decay_rate", "parameter", start=1.0 / 80.0, unit="1/s3", min=0.0,
                     description="r_decay; gamma *= exp(-(t - t_t)^2 * dt * r_decay) between events"),
            Variable("action_limit", "parameter", start=1.0, unit="deg/s", min=0.0,
                     description="the action is clipped to [-action_limit, action_limit]"),
            Variable("spatial_sd", "parameter", start=np.inf, unit="m", min=0.0,
                     description="extension: sd of the seen-felt hand distance under a common cause (causal "
                                 "inference over space); inf = the paper's model, gamma ignores space"),
            Variable("action_time_constant", "parameter", start=0.1, unit="s", min=0.0,
                     description="tau of the action law a <- a + dt (a_dot - a/tau): the leaky (reflex) "
                                 "action; inf = the paper's eq. 7, a pure integrator"),
            Variable("q_shoulder", "input", start=np.nan, unit="deg",
                     description="s_p: sensed shoulder angle (NaN until the body feeds it)"),
            Variable("q_elbow", "input", start=np.nan, unit="deg",
                     description="s_p: sensed elbow angle (NaN until the body feeds it)"),
            Variable("visual_drive", "input", start=(0.0, 0.0), unit="deg/s", **joint,
                     description="J^T (s_v - g(mu)) / Sigma_v from the decoder, at this step's mu"),
            Variable("visual_error", "input", start=0.0, unit="1", min=0.0,
                     description="1/2 e^T Sigma_v^-1 e from the decoder, e = s_v - g(mu), at this step's mu"),
            Variable("visual_stiffness", "input", start=0.0, unit="1/s", min=0.0,
                     description="largest eigenvalue of J^T J / Sigma_v, for the stability guard"),
            *goal_inputs(),
            Variable("seen_hand", "input", start=(np.nan, np.nan), unit="m", **joint,
                     description="the seen (rubber) hand (x, y); read only when spatial_sd is finite"),
            Variable("hand_x", "input", start=np.nan, unit="m",
                     description="the felt hand: x of the sensed arm's hand; read only when spatial_sd is finite"),
            Variable("hand_y", "input", start=np.nan, unit="m",
                     description="the felt hand: y of the sensed arm's hand; read only when spatial_sd is finite"),
            Variable("visual_time", "input", start=-np.inf, unit="s",
                     description="time of the last observed visual touch event (-inf: none yet)"),
            Variable("tactile_time", "input", start=-np.inf, unit="s",
                     description="time of the last observed tactile event (-inf: none yet)"),
            Variable("mu", unit="deg", **joint, **state, description="belief of the joint angles (shoulder, elbow)"),
            Variable("u_shoulder", unit="deg/s", **state, description="action a: commanded shoulder velocity"),
            Variable("u_elbow", unit="deg/s", **state, description="action a: commanded elbow velocity"),
            Variable("action_rate", unit="deg/s2", **joint, **state, description="a_dot (shoulder, elbow)"),
            Variable("gamma", unit="1", min=0.0, max=1.0, **state,
                     description="belief that seen and felt touch share a cause; weights vision"),
            Variable("free_energy", unit="1", **state,
                     description="sum (s_p - mu)^2 / (2 Sigma_p) + gamma * visual_error, at the step's start mu"),
        ])

    def publish_initial(self):
        """mu = mu0, gamma = gamma0, a = a_dot = 0, free energy NaN, no events seen: the decoder,
        earlier in the step order, reads mu0 in initialization mode."""
        batch = self.batch_size
        self.values["mu"] = self.values["mu0"].copy()
        self.values["gamma"] = self.values["gamma0"].copy()
        self.values["u_shoulder"], self.values["u_elbow"] = np.zeros(batch), np.zeros(batch)
        self.values["action_rate"] = np.zeros((batch, 2))
        self.values["free_energy"] = np.full(batch, np.nan)
        # Event bookkeeping (observe_events): last seen times, and events seen since the last Bayes update.
        self._events = (np.full(batch, -np.inf), np.full(batch, -np.inf), np.zeros(batch, bool), np.zeros(batch, bool))

    def check_parameters(self):
        for name in ("proprioceptive_variance", "sync_sd", "async_density", "action_limit"):
            bad = self.values[name][~((self.values[name] > 0) & np.isfinite(self.values[name]))]
            if bad.size:
                raise ComponentError(f"{self.name}.{name} must be positive and finite, got {float(bad[0])!r}")
        spatial = self.values["spatial_sd"]
        if np.any(~(spatial > 0)):
            raise ComponentError(f"{self.name}.spatial_sd must be positive (inf: the paper's model), "
                                 f"got {float(spatial[~(spatial > 0)][0])!r}")
        tau = self.values["action_time_constant"]
        if np.any(~(tau > 0)):  # inf is allowed (the paper's law); 0 and NaN are not
            raise ComponentError(f"{self.name}.action_time_constant must be positive (inf: the paper's law), "
                                 f"got {float(tau[~(tau > 0)][0])!r}")
        if not np.all(np.isfinite(self.values["mu0"])):
            raise ComponentError(f"{self.name}.mu0 must be finite, got {self.values['mu0'].tolist()!r}")

    def _sensed(self, proprioception=True):
        """s_p as (B, 2) after checking the inputs; StepFailure names the bad one."""
        names = ("visual_drive", "visual_error", "visual_stiffness", "goal_drive", "goal_error", "goal_stiffness")
        for name in ("q_shoulder", "q_elbow") + names if proprioception else names:
            _require_finite(name, self.values[name])
        for name in ("visual_time", "tactile_time"):
            _require_finite(name, self.values[name], allow_minus_inf=True)
        return np.stack([self.values["q_shoulder"], self.values["q_elbow"]], axis=1)

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
                raise StepFailure(f"{name} is not finite ({first}) in {_trials(bad)} (brain.spatial_sd is finite, "
                                  f"so the seen and the felt hand must be connected)")
        return seen, felt

    def initialize(self):
        """mu = mu0, a = a_dot = 0, gamma = gamma0, free energy NaN.

        F is the free energy each step descends, so it exists from the first step on: at
        initialization s_p may not have arrived (the body comes after the brain in the agreed
        order, and the brain would see its start value), so row 0 of a recorded F is NaN.
        """
        self.check_parameters()
        self.publish_initial()  # again: parameters may have been set in initialization mode
        self._sensed(proprioception=False)

    def step(self, t, h):
        v = self.values
        s_p, mu, variance = self._sensed(), v["mu"], v["proprioceptive_variance"]
        visual_time, tactile_time = v["visual_time"], v["tactile_time"]

        # 1. gamma: Bayes once a new visual and a new tactile event have both been seen.
        pair, *events = observe_events(*self._events, visual_time, tactile_time)
        spatial = spatial_likelihood(*self._hands(), v["spatial_sd"])
        gamma = update_gamma(v["gamma"], pair, visual_time, tactile_time, t + h, h, v["gamma0"],
                             v["sync_sd"], v["async_density"], v["decay_rate"], spatial)

        number = stability_number(h, variance, gamma, v["visual_stiffness"]) + h * v["goal_stiffness"]
        unstable = ~(number < STABILITY_LIMIT)
        if unstable.any():
            i = np.flatnonzero(unstable)[0]
            raise StepFailure(
                f"step too large for stable explicit Euler in {_trials(unstable)}: dt * (1/Sigma_p + gamma * "
                f"visual_stiffness{' + goal_stiffness' if v['goal_stiffness'][i] else ''}) = {number[i]:.4g} >= 2 "
                f"(dt = {h:g} s, Sigma_p = {variance[i]:g}, gamma = {gamma[i]:.4g}, visual_stiffness = "
                f"{v['visual_stiffness'][i]:.4g} 1/s); use a smaller step or a larger visual_variance")

        leaky = ~(h / v["action_time_constant"] < STABILITY_LIMIT)
        if leaky.any():
            i = np.flatnonzero(leaky)[0]
            raise StepFailure(
                f"step too large for the leaky action in {_trials(leaky)}: dt / action_time_constant = "
                f"{h / v['action_time_constant'][i]:.4g} >= 2 (dt = {h:g} s, action_time_constant = "
                f"{v['action_time_constant'][i]:g} s); use a smaller step or a longer action_time_constant")

        # 2. belief, 3. a_dot from the updated belief (released agent's order), 4. the action law.
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is caught just below, by name
            new_mu, a_dot, action = euler_step(mu, np.stack([v["u_shoulder"], v["u_elbow"]], axis=1), s_p, gamma,
                                               v["visual_drive"], variance, v["action_limit"], h,
                                               v["action_time_constant"], v["goal_drive"])
            energy = free_energy(s_p, mu, gamma, v["visual_error"], variance)
            if np.any(v["goal_error"]):
                energy = energy + v["goal_error"]
        for name, value in (("mu", new_mu), ("action_rate", a_dot), ("free_energy", energy)):
            _require_finite(name, value)

        # Commit only after every check passed: a failed step leaves the state as it was.
        self._events = tuple(events)
        v["mu"], v["gamma"], v["action_rate"], v["free_energy"] = new_mu, gamma, a_dot, energy
        v["u_shoulder"], v["u_elbow"] = action[:, 0].copy(), action[:, 1].copy()
