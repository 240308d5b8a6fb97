"""The paper's causal inference of gamma from the touches' timing: does the seen (rubber) hand cause the felt touch?
(paper eqs. 8-9; the causal model's inference over space and time is body_inference.py).

gamma = p(c1 | t_v, t_t) is the belief that the visual and the tactile event share one
source, the seen hand. It weights the visual drive of the belief (paper eq. 6).

Equation numbers are those of the compiled paper: eq. 8 is Bayes' rule (source label
``eq:8``), eq. 9 the update rule (source label ``eq:11``; docs/design.md's "eqs. 10-11").

Choices the paper leaves open (docs/design.md wins where it speaks):
- The decay measures time from the last *tactile* event t_t (docs/design.md and the released
  agent), not from max(t_v, t_t) as the paper's eq. 9 prints.
- Before any tactile event has been observed there is no time since touch to measure: the
  decay is skipped and gamma holds. Gamma is then still at its start and floor gamma0 (only
  Bayes' rule raises it, and that needs a touch), so this matches the released agent's
  sentinel t_t = -60 s while avoiding inf arithmetic (and inf * 0 when r_decay = 0).
- When p1 * gamma + p2 * (1 - gamma) underflows to 0 (gamma = 1 and a delay so large
  that p1 = 0), the posterior is taken equal to the prior instead of 0/0.

An extension, off by default (``spatial_sd = inf``): causal inference over space as well as
time (Samad, Chung & Shams 2015, PLoS ONE 10:e0117178). Under a common cause the seen and the
felt hand are at the same place up to Gaussian noise of sd sigma_s; under separate causes their
distance is uninformative. Bayes' rule then multiplies p1 by :func:`spatial_likelihood`, the
Gaussian factor exp(-d^2 / (2 sigma_s^2)) of the distance d between the seen and the felt hand,
taken relative to its peak (the density under separate causes is set equal to the common-cause
density at d = 0), so that overlapping hands leave the paper's model as it is, and sigma_s = inf
is the paper's model exactly.

All functions are vectorised over the batch: arguments are arrays of shape (B,).
"""
from __future__ import annotations

import numpy as np


def synchrony_likelihood(visual_time, tactile_time, sync_sd):
    """p(t_v, t_t | c1): zero-mean normal density of the delay t_v - t_t, sd ``sync_sd`` (1/s).

    The likelihood under a common cause in paper eq. 8; scipy's density, not a hand-written one.

    Parameters
    ----------
    visual_time, tactile_time : array_like, (B,)
        t_v and t_t, s (finite).
    sync_sd : array_like, (B,)
        s.

    Returns
    -------
    ndarray, (B,)
        The density, 1/s.
    """
    from scipy.stats import norm  # here, not at the top: a refused command never pays for scipy.stats

    return norm.pdf(np.asarray(visual_time) - np.asarray(tactile_time), loc=0.0, scale=sync_sd)


def spatial_likelihood(seen_hand, felt_hand, spatial_sd):
    """The extension's spatial factor: exp(-|seen - felt|^2 / (2 spatial_sd^2)), (B,); 1 where spatial_sd = inf.

    Where spatial_sd is inf the positions are not read (they may be NaN) and the factor is exactly 1.

    Parameters
    ----------
    seen_hand, felt_hand : array_like, (B, 2)
        The seen (rubber) and the felt (sensed) hand, m.
    spatial_sd : array_like, (B,)
        sigma_s, m; inf: the paper's model.

    Returns
    -------
    ndarray, (B,)
        The factor, in [0, 1].
    """
    spatial_sd = np.asarray(spatial_sd, dtype=float)
    off = np.isinf(spatial_sd)
    distance2 = np.where(off, 0.0, ((np.asarray(seen_hand) - np.asarray(felt_hand)) ** 2).sum(axis=-1))
    return np.where(off, 1.0, np.exp(-distance2 / (2.0 * np.where(off, 1.0, spatial_sd) ** 2)))


def posterior_common_cause(gamma, visual_time, tactile_time, sync_sd, async_density, spatial=1.0):
    """Paper eq. 8 (and the first case of eq. 9): Bayes' rule with prior gamma.

    gamma' = p1 gamma / (p1 gamma + p2 (1 - gamma)), p1 = synchrony_likelihood(...) * spatial,
    p2 = async_density, the uniform density of the delay under two separate causes. ``spatial`` is
    the extension's :func:`spatial_likelihood` (1: the paper's model).

    Parameters
    ----------
    gamma : array_like, (B,)
        The prior, in [0, 1].
    visual_time, tactile_time : array_like, (B,)
        t_v and t_t, s (finite).
    sync_sd, async_density : array_like, (B,)
        s and 1/s.
    spatial : float or array_like, (B,)
        The spatial factor, 1.

    Returns
    -------
    ndarray, (B,)
        gamma', in [0, 1]; gamma where the evidence underflows to 0.
    """
    p1 = synchrony_likelihood(visual_time, tactile_time, sync_sd) * spatial
    numerator = p1 * gamma
    evidence = numerator + async_density * (1.0 - gamma)
    safe = np.where(evidence > 0, evidence, 1.0)
    return np.where(evidence > 0, numerator / safe, gamma)


def decayed(gamma, time, tactile_time, step, decay_rate):
    """Paper eq. 9, second case: gamma * exp(-((t - t_t)^2 / (1/dt)) * r_decay).

    t_t is the last observed tactile event; where none has been observed yet (t_t = -inf)
    gamma is returned unchanged (see the module notes).

    Parameters
    ----------
    gamma : array_like, (B,)
        In [0, 1].
    time, tactile_time : float or array_like, (B,)
        t and t_t, s (t_t may be -inf).
    step : float
        dt, s.
    decay_rate : array_like, (B,)
        r_decay, 1/s^3.

    Returns
    -------
    ndarray, (B,)
        The decayed gamma.
    """
    touched = np.isfinite(tactile_time)
    since = np.where(touched, time - np.where(touched, tactile_time, 0.0), 0.0)
    return np.where(touched, gamma * np.exp(-(since ** 2 / (1.0 / step)) * decay_rate), gamma)


def observe_events(seen_visual, seen_tactile, pending_visual, pending_tactile, visual_time, tactile_time):
    """Which trials have a new pair of events, the trigger of Bayes' rule in eq. 9, and the bookkeeping after it.

    seen_visual, seen_tactile: the event times observed at the previous step (-inf: none yet).
    An event is new when its time differs from the one seen before (and is finite). Pure: the caller
    commits the state it returns.

    Parameters
    ----------
    seen_visual, seen_tactile : ndarray, (B,)
        The event times observed at the previous step, s (-inf: none yet).
    pending_visual, pending_tactile : ndarray of bool, (B,)
        A new event of that kind observed since the last Bayes update.
    visual_time, tactile_time : ndarray, (B,)
        The last event times observed now, s.

    Returns
    -------
    tuple of five ndarray, (B,) each
        ``(pair, seen_visual, seen_tactile, pending_visual, pending_tactile)``: pair (bool), a new visual
        and a new tactile event both observed since the last Bayes update; then the state for the next
        step, the pending flags cleared where a pair fired.
    """
    pending_visual = pending_visual | ((visual_time != seen_visual) & np.isfinite(visual_time))
    pending_tactile = pending_tactile | ((tactile_time != seen_tactile) & np.isfinite(tactile_time))
    pair = pending_visual & pending_tactile
    return (pair, np.array(visual_time, dtype=float), np.array(tactile_time, dtype=float),
            pending_visual & ~pair, pending_tactile & ~pair)


def update_gamma(gamma, new_pair, visual_time, tactile_time, time, step, gamma0,
                 sync_sd=0.2, async_density=0.5, decay_rate=1.0 / 80.0, spatial=1.0):
    """One step of paper eq. 9 for each trial, then the clamp to [gamma0, 1].

    Parameters
    ----------
    gamma : array_like, (B,)
        The previous step's gamma.
    new_pair : ndarray of bool, (B,)
        A new visual and a new tactile event have both been observed since the last Bayes update of
        that trial (:func:`observe_events`); Bayes' rule there, the decay elsewhere.
    visual_time, tactile_time : array_like, (B,)
        The last observed event times, s (-inf before any).
    time : float
        The time the inputs describe, s.
    step : float
        The communication step dt, s.
    gamma0 : array_like, (B,)
        The floor.
    sync_sd, async_density, decay_rate : array_like, (B,)
        s, 1/s, 1/s^3.
    spatial : float or array_like, (B,)
        The extension's :func:`spatial_likelihood` (1: the paper's model).

    Returns
    -------
    ndarray, (B,)
        gamma, in [gamma0, 1].
    """
    decay = decayed(gamma, time, tactile_time, step, decay_rate)
    if not np.any(new_pair):  # most steps: no trial takes Bayes' branch, so skip scipy's density (same numbers)
        return np.clip(decay, gamma0, 1.0)
    # Event times may be -inf where no pair is due; keep them out of the density (no inf - inf).
    visual = np.where(new_pair, visual_time, 0.0)
    tactile = np.where(new_pair, tactile_time, 0.0)
    bayes = posterior_common_cause(gamma, visual, tactile, sync_sd, async_density, spatial)
    return np.clip(np.where(new_pair, bayes, decay), gamma0, 1.0)
