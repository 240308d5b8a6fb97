"""The brains' one base: a step of belief and action and its guards (docs/model.md); the step's equations are
:mod:`rhi.components.brain.action_law`'s, the variables every brain declares :mod:`rhi.components.brain.contract`'s.

A brain (:class:`BeliefBrain`) holds the belief mu of the arm's two joint angles and the action a. The
models differ only in how fast the belief moves; each step of every model, for each of the B trials:

1. the inputs are checked finite, by name (event times may be -inf: no event yet);
2. the model's own rate (:meth:`BeliefBrain.rate`): gamma, mu_dot, the stiffness number dt * k of the
   belief's decay, the free energy and any state of the model's own (the paper's brain:
   :mod:`rhi.components.brain.integrator`; the causal model's: :mod:`rhi.components.brain.causal_brain`);
3. the guards of explicit Euler: the belief is stable only while the stiffness number < 2, the leaky
   action only while dt / tau < 2;
4. mu <- mu + dt * mu_dot, then a_dot from the UPDATED mu (eq. 7) and the action law, the released agent's order
   (:func:`~rhi.components.brain.action_law.euler_step`);
5. mu, a_dot and the free energy checked finite; only then is anything committed, so a failed step
   leaves the state as it was.

The guards raise :class:`~rhi.components.component.StepFailure` naming the variable, the value and the trials
(:func:`require_finite`, :func:`trials_text`); the master then stops the run.
"""
from __future__ import annotations

import abc
from types import MappingProxyType
from typing import NamedTuple

import numpy as np

from .action_law import euler_step
from .contract import contract
from .touch_timing import observe_events
from ..component import Component, ComponentError, StepFailure
from ..variables import Variable

STABILITY_LIMIT = 2.0  # explicit Euler on a linear decay of rate k is stable iff dt * k < 2
GOAL_INPUTS = ("goal_drive", "goal_error", "goal_stiffness")  # rhi.components.brain.goal.goal_inputs
EVENT_INPUTS = ("visual_time", "tactile_time")


def trials_text(mask) -> str:
    """The trials where ``mask`` is true, for a message: "trial 3" or "trials 0, 2, ..." (at most five shown).

    Parameters
    ----------
    mask : array_like of bool, (B,)

    Returns
    -------
    str
    """
    indices = np.flatnonzero(mask)
    shown = ", ".join(map(str, indices[:5])) + (", ..." if len(indices) > 5 else "")
    return f"trial{'s' if len(indices) > 1 else ''} {shown}"


def require_finite(name, value, allow_minus_inf=False):
    """Raise StepFailure naming the variable, the first bad value and the trials, if any value is not finite.

    Parameters
    ----------
    name : str
        The variable's name, as the message gives it.
    value : array_like, (B, ...)
        Batch first.
    allow_minus_inf : bool
        -inf is allowed (an event time: no event yet); NaN and +inf are not.

    Raises
    ------
    StepFailure
        "<name> is not finite (<value>) in trial(s) ...".
    """
    value = np.asarray(value)
    if np.isfinite(value).all():  # the usual case, checked every step: one pass
        return
    bad = np.isnan(value) | (value == np.inf) if allow_minus_inf else ~np.isfinite(value)
    per_trial = bad.reshape(len(value), -1).any(axis=1)
    if per_trial.any():
        raise StepFailure(f"{name} is not finite ({value[bad].flat[0]}) in {trials_text(per_trial)}")


class BeliefRate(NamedTuple):
    """What a model computes in a step, before the shared guards and the Euler step (:meth:`BeliefBrain.rate`).

    Attributes
    ----------
    gamma : ndarray, (B,)
        This step's belief in a common cause, in [0, 1].
    mu_dot : ndarray, (B, 2)
        The belief's rate, deg/s.
    stiffness : ndarray, (B,)
        The stability number dt * k of the belief's linear decay, dimensionless (explicit Euler: stable below 2).
    free_energy : ndarray, (B,)
        F at the step's start mu, dimensionless.
    state : mapping
        The model's further state, committed with the step (:meth:`BeliefBrain.commit`; by default outputs by
        name, e.g. ``gamma_timing``).
    """

    gamma: np.ndarray
    mu_dot: np.ndarray
    stiffness: np.ndarray
    free_energy: np.ndarray
    state: MappingProxyType = MappingProxyType({})  # read-only, so the one default cannot change


class BeliefBrain(Component, abc.ABC):
    """A brain of belief mu and action a for B trials: the shared step, guards and action law.

    A model derives from it, declares only its own variables (the contract's are declared once, :func:`~rhi.components.brain.contract.contract`)
    and implements :meth:`rate`, :meth:`stiffness_terms` and the publishing of gamma.

    Parameters
    ----------
    name : str
        The instance name in a system.
    own : list of Variable or str
        The model's own parameters, inputs and outputs. A contract variable's name (a str) places that
        variable there; those not named follow the contract's order, each group before the model's own of its
        causality. (An exported brain names them all, so that its FMU's value references keep their order.)
    gamma, free_energy : str
        What the model's ``gamma`` is and its ``free_energy`` sums (:func:`~rhi.components.brain.contract.contract`).

    Attributes
    ----------
    finite_inputs : tuple of str
        The model's own inputs checked finite every step, between s_p and the goal's.
    stiffness_remedy : str
        What the stability message suggests besides a smaller step ("" for nothing).
    """

    finite_inputs: tuple[str, ...] = ()
    stiffness_remedy = ""

    def __init__(self, name: str, own: list[Variable], gamma: str, free_energy: str = "F at the step's start mu"):
        shared = {v.name: v for group in contract(gamma, free_energy).values() for v in group}
        named = [shared[v] if isinstance(v, str) else v for v in own]  # KeyError: not a contract variable's name
        rest = [v for v in shared.values() if v.name not in own]

        def group(variable):
            return variable.causality if variable.causality in ("parameter", "input") else "output"  # or local

        super().__init__(name, [v for causality in ("parameter", "input", "output")
                                for v in [*(r for r in rest if group(r) == causality),
                                          *(n for n in named if group(n) == causality)]])

    @abc.abstractmethod
    def rate(self, t, h, s_p, pair) -> BeliefRate:
        """The model's gamma, mu_dot, stiffness number and free energy; may raise StepFailure.

        Parameters
        ----------
        t, h : float
            The step's start time and size, s.
        s_p : ndarray, (B, 2)
            Sensed joint angles, deg (checked finite).
        pair : ndarray of bool, (B,)
            A new visual and a new tactile event both seen since the last Bayes update
            (:func:`~rhi.components.brain.touch_timing.observe_events`).

        Returns
        -------
        BeliefRate
        """

    @abc.abstractmethod
    def stiffness_terms(self, i, rate: BeliefRate) -> tuple[str, str]:
        """Trial ``i``'s stiffness number in words, for the stability message.

        Parameters
        ----------
        i : int
            The first unstable trial.
        rate : BeliefRate
            This step's.

        Returns
        -------
        tuple of str
            (formula, values), e.g. ("1/Sigma_p + gamma * visual_stiffness", "Sigma_p = 1, gamma = 0.5,
            visual_stiffness = 3 1/s").
        """

    def publish_initial(self):
        """mu = mu0, a = a_dot = 0, free energy NaN (s_p may not have arrived yet), no events seen.

        A model publishes its gamma after calling this.
        """
        batch, v = self.batch_size, self.values
        v["mu"] = v["mu0"].copy()
        v["u_shoulder"], v["u_elbow"] = np.zeros(batch), np.zeros(batch)
        v["action_rate"] = np.zeros((batch, 2))
        v["free_energy"] = np.full(batch, np.nan)
        # Event bookkeeping (observe_events): last seen times, and events seen since the last Bayes update.
        self._events = (np.full(batch, -np.inf), np.full(batch, -np.inf), np.zeros(batch, bool), np.zeros(batch, bool))

    def initialize(self):
        """Check the parameters, then publish again: parameters may have been set in initialization mode."""
        self.check_parameters()
        self.publish_initial()

    def require_positive_finite(self, *names):
        """Raise ComponentError naming the first parameter of ``names`` with a value not positive and finite."""
        for name in names:
            bad = self.values[name][~((self.values[name] > 0) & np.isfinite(self.values[name]))]
            if bad.size:
                raise ComponentError(f"{self.name}.{name} must be positive and finite, got {float(bad[0])!r}")

    def check_parameters(self):
        """The parameters every brain shares: Sigma_p and the action's clip positive and finite, tau > 0
        (inf: the paper's law), mu0 finite. A model checks its own after these."""
        self.require_positive_finite("proprioceptive_variance", "action_limit")
        tau = self.values["action_time_constant"]
        if np.any(~(tau > 0)):  # inf is allowed (the paper's law); 0 and NaN are not
            raise ComponentError(f"{self.name}.action_time_constant must be positive (inf: the paper's law), "
                                 f"got {float(tau[~(tau > 0)][0])!r}")
        if not np.all(np.isfinite(self.values["mu0"])):
            raise ComponentError(f"{self.name}.mu0 must be finite, got {self.values['mu0'].tolist()!r}")

    def check_inputs(self, proprioception=True):
        """StepFailure naming the first input not finite: s_p (unless ``proprioception`` is false: at
        initialization it may not have arrived), the model's :attr:`finite_inputs`, the goal's, the event
        times (which may be -inf)."""
        names = (("q_shoulder", "q_elbow") if proprioception else ()) + self.finite_inputs + GOAL_INPUTS
        for name in names:
            require_finite(name, self.values[name])
        for name in EVENT_INPUTS:
            require_finite(name, self.values[name], allow_minus_inf=True)

    def check_stiffness(self, rate: BeliefRate, h):
        """StepFailure where explicit Euler of the belief would be unstable: stiffness number >= 2 (or NaN)."""
        unstable = ~(rate.stiffness < STABILITY_LIMIT)
        if unstable.any():
            i = np.flatnonzero(unstable)[0]
            formula, values = self.stiffness_terms(i, rate)
            remedy = f" or {self.stiffness_remedy}" if self.stiffness_remedy else ""
            raise StepFailure(f"step too large for stable explicit Euler in {trials_text(unstable)}: dt * ({formula}) "
                              f"= {rate.stiffness[i]:.4g} >= 2 (dt = {h:g} s, {values}); use a smaller step{remedy}")

    def check_leak(self, h):
        """StepFailure where explicit Euler of the leaky action would be unstable: dt / tau >= 2."""
        tau = self.values["action_time_constant"]
        leaky = ~(h / tau < STABILITY_LIMIT)
        if leaky.any():
            i = np.flatnonzero(leaky)[0]
            raise StepFailure(
                f"step too large for the leaky action in {trials_text(leaky)}: dt / action_time_constant = "
                f"{h / tau[i]:.4g} >= 2 (dt = {h:g} s, action_time_constant = {tau[i]:g} s); use a smaller step "
                f"or a longer action_time_constant")

    def step(self, t, h):
        """Advance from ``t`` to ``t + h``: the steps of the module notes; StepFailure leaves the state as it was."""
        v = self.values
        self.check_inputs()
        s_p = np.stack([v["q_shoulder"], v["q_elbow"]], axis=1)
        pair, *events = observe_events(*self._events, v["visual_time"], v["tactile_time"])
        rate = self.rate(t, h, s_p, pair)
        self.check_stiffness(rate, h)
        self.check_leak(h)
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is named just below
            new_mu, a_dot, action = euler_step(v["mu"], rate.mu_dot, np.stack([v["u_shoulder"], v["u_elbow"]], axis=1),
                                               s_p, v["proprioceptive_variance"], v["action_limit"],
                                               v["action_time_constant"], h)
        for name, value in (("mu", new_mu), ("action_rate", a_dot), ("free_energy", rate.free_energy)):
            require_finite(name, value)

        # Commit only after every check passed.
        self._events = tuple(events)
        v["mu"], v["gamma"], v["action_rate"], v["free_energy"] = new_mu, rate.gamma, a_dot, rate.free_energy
        v["u_shoulder"], v["u_elbow"] = action[:, 0].copy(), action[:, 1].copy()
        self.commit(rate.state)

    def commit(self, state):
        """Commit the model's own state once the step has passed every check: each item of ``state`` (a
        :attr:`BeliefRate.state`) into the output of that name; a model with more state extends this."""
        for name, value in state.items():
            self.values[name] = value


class PerceptualNoise:
    """A brain whose trials each draw perceptual timing noise from a generator of their own (``self._generators``,
    one numpy Generator per trial, made at initialization): a failed step leaves the generators as they were, so
    a trial retried or dropped does not consume its participant's draws; :meth:`commit` moves them on.

    Mixed in before :class:`BeliefBrain` (``class MyBrain(PerceptualNoise, BeliefBrain)``); the state a step
    returns carries the generators' new states under ``"streams"``.
    """

    _generators: list

    def _timing_noise(self, pair):
        """A standard normal from each trial's generator where ``pair`` (0 elsewhere), (B,), and the generators'
        states after the draw by trial; the generators are put back as they were."""
        noise, after = np.zeros(len(pair)), {}
        for i in np.flatnonzero(pair):
            stream = self._generators[i].bit_generator
            before = stream.state
            noise[i] = self._generators[i].standard_normal()
            after[i], stream.state = stream.state, before
        return noise, after

    def commit(self, state):
        """The step's state, and the generators moved past this step's timing noise."""
        state = dict(state)
        for i, after in state.pop("streams").items():
            self._generators[i].bit_generator.state = after
        super().commit(state)
