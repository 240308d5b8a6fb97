"""The step's equations every brain shares: the action (paper eq. 7 and the action law), a reach goal's pull on
the belief, and one explicit Euler step of belief and action in the released agent's order.

:class:`rhi.components.brain.base.BeliefBrain` takes each step through them after its guards.
"""
from __future__ import annotations

import numpy as np


def action_rate(s_p, mu, proprioceptive_variance):
    """Paper eq. 7 as docs/design.md and the released agent write it: a_dot = -(s_p - mu)/Sigma_p.

    The paper's extra factor dt (from ds/da = dt) is left out, as in the released agent.

    Parameters
    ----------
    s_p, mu : ndarray, (B, 2)
        Sensed joint angles and belief, deg.
    proprioceptive_variance : ndarray, (B,)
        Sigma_p, deg^2.

    Returns
    -------
    ndarray, (B, 2)
        a_dot, deg/s^2 (with Sigma_p's implicit unit rate, 1/s per 1/deg^2).
    """
    return -(s_p - mu) / proprioceptive_variance[:, None]



def action_update(action, a_dot, action_time_constant, action_limit, h):
    """The action law: a <- clip(a + h * (a_dot - a/tau), -limit, limit).

    tau = ``action_time_constant``: inf is the paper's law a <- clip(a + h * a_dot) (computed as written,
    so bit for bit the released agent's), a finite tau the leaky integrator whose fixed point is
    a = tau * a_dot (:mod:`rhi.components.brain.integrator`'s notes).

    Parameters
    ----------
    action, a_dot : ndarray, (B, 2)
        The action a (deg/s) and its rate (deg/s^2).
    action_time_constant : ndarray, (B,)
        tau, s; inf for the paper's law.
    action_limit : ndarray, (B,)
        The clip, deg/s.
    h : float
        The step, s.

    Returns
    -------
    ndarray, (B, 2)
        The new action, deg/s.
    """
    tau, limit = action_time_constant[:, None], action_limit[:, None]
    paper = np.isinf(tau)
    leaky = action + h * (a_dot - action / np.where(paper, 1.0, tau))
    return np.clip(np.where(paper, action + h * a_dot, leaky), -limit, limit)



def add_goal_drive(mu_dot, goal_drive):
    """mu_dot plus a reach goal's pull on the belief, unweighted by gamma; mu_dot itself (same bits) without a goal.

    Source: the released agent adds its attractor term so (``FepAgent.active_inference_step``: mu_dot =
    dF_dmu_vis + dF_dmu_attr + proprioception); the term itself: a goal decoder's drive or
    :mod:`rhi.components.brain.goal`.

    Parameters
    ----------
    mu_dot : ndarray, (B, 2)
        The model's belief rate, deg/s.
    goal_drive : ndarray, (B, 2) or None
        The goal's pull, deg/s; all 0 or None: no goal.

    Returns
    -------
    ndarray, (B, 2)
        deg/s.
    """
    if goal_drive is not None and np.any(goal_drive):  # no goal: no addition, so not even a -0.0 changes
        return mu_dot + goal_drive
    return mu_dot



def euler_step(mu, mu_dot, action, s_p, proprioceptive_variance, action_limit, action_time_constant, h):
    """One explicit Euler step of belief and action in the released agent's order.

    mu <- mu + h * mu_dot; a_dot from the UPDATED mu (:func:`action_rate`, eq. 7: the action already
    pursues the new belief, as the released agent computes ``a_dot`` after updating ``self.mu``); the
    action by the action law (:func:`action_update`).

    Parameters
    ----------
    mu, mu_dot : ndarray, (B, 2)
        Belief (deg) and the model's belief rate (deg/s).
    action, s_p : ndarray, (B, 2)
        Action (deg/s) and sensed joint angles (deg).
    proprioceptive_variance, action_limit, action_time_constant : ndarray, (B,)
        Sigma_p (deg^2), the action's clip (deg/s), tau (s; inf: the paper's law).
    h : float
        The step, s.

    Returns
    -------
    tuple of ndarray, each (B, 2)
        (new_mu deg, a_dot deg/s^2, new_action deg/s).
    """
    new_mu = mu + h * mu_dot
    a_dot = action_rate(s_p, new_mu, proprioceptive_variance)
    return new_mu, a_dot, action_update(action, a_dot, action_time_constant, action_limit, h)
