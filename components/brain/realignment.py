"""The ownership model's drift: a slow realignment b of the felt arm toward the seen one, and the belief that
follows the realigned proprioception (docs/model.md, "The ownership model").

One function per equation, each vectorised over the batch of B trials:

- :func:`realignment_target`: where b settles, v w rho (x_v - s_p); b steps toward it exactly
  (:func:`rhi.components.brain.ownership_inference.relaxation_step` at rate k v);
- :func:`felt_variance_step` and :func:`visual_weight`: proprioception fading at rest, and the seen hand's weight;
- :func:`belief_rate` and :func:`free_energy`: the belief follows the realigned proprioception s_p + b.

The beliefs that drive it (ownership gamma, the coupling rho, whether a hand is seen) are
:mod:`rhi.components.brain.ownership_inference`'s.
"""
from __future__ import annotations

import numpy as np


def realignment_target(seen_pose, felt_pose, weight, coupling, seen=1.0):
    """Where the realignment b settles: b* = v w rho (x_v - s_p), (B, 2), deg.

    w is the fraction of the way a seen hand pulls the felt one (Noel et al. 2018, Sci Rep 8:15819: 30-40 %,
    coupling weight 0.34-0.44, measured with no touch); rho the coupling belief, the probability that the
    seen hand lies where the felt one is (docs/model.md); v is 1 while a hand is seen, 0 while none is
    (:func:`~rhi.components.brain.ownership_inference.seen_hand`). Joint angles: a fraction of the way is the same fraction in hand space to first order
    (the arm's Jacobian is linear).

    Parameters
    ----------
    seen_pose, felt_pose : array_like, (B, 2)
        x_v (the pose encoder's reading of the image) and s_p (sensed), deg.
    weight, coupling : array_like, (B,)
        w and rho, 1.
    seen : array_like, (B,) or scalar
        v, 1 or 0.

    Returns
    -------
    ndarray, (B, 2)
        deg.
    """
    scale = np.asarray(weight, float) * np.asarray(coupling, float) * np.asarray(seen, float)
    return scale[:, None] * (np.asarray(seen_pose, float) - np.asarray(felt_pose, float))



def felt_variance_step(variance, base_variance, fading_rate, movement, step):
    """The proprioceptive variance Sigma_p(t): it rises while the arm rests and recovers as it moves, (B,), deg^2.

    A resting, unseen limb's felt position drifts and grows uncertain (Wann & Ibrahim 1992, Exp Brain Res
    91:162: position sense of a limb kept still drifts over time; Rohde, Di Luca & Ernst 2011 attribute the
    slow build-up of the proprioceptive drift over minutes to it). Without a fresh movement signal the
    position estimate diffuses as a random walk, so its variance grows linearly: dSigma_p/dt = phi Sigma_p0,
    phi the fading rate (free, fitted: 1/phi is the time for the variance to double). A movement refreshes it:
    the excess over Sigma_p0 falls by exp(-|ds_p| / sqrt(Sigma_p0)) for a movement |ds_p| (deg, summed over the
    joints), i.e. by e for a movement of one proprioceptive sd. Exact over the step for a linear growth followed
    by the step's movement.

    Parameters
    ----------
    variance : array_like, (B,)
        Sigma_p at the step's start, deg^2.
    base_variance : array_like, (B,)
        Sigma_p0, the rested-limb value after movement (the paper's Sigma_p), deg^2.
    fading_rate : array_like, (B,)
        phi, 1/s (>= 0; 0: a constant Sigma_p, the paper's).
    movement : array_like, (B,)
        |ds_p| over the step, deg.
    step : float
        h, s.

    Returns
    -------
    ndarray, (B,)
        Sigma_p after the step, deg^2.
    """
    base = np.asarray(base_variance, float)
    grown = np.asarray(variance, float) - base + np.asarray(fading_rate, float) * base * step
    return base + grown * np.exp(-np.asarray(movement, float) / np.sqrt(base))



def visual_weight(felt_variance, base_variance, base_weight):
    """w(t) = Sigma_p / (Sigma_p + Sigma_v), the fraction of the way a seen hand pulls the felt one, (B,).

    Reliability-weighted fusion of two position estimates (Ernst & Banks 2002, Nature 415:429; van Beers,
    Sittig & Denier van der Gon 1999 for vision and proprioception of the hand): the seen hand's weight is the
    felt one's variance over the sum. Sigma_v is set by the measured weight w0 at the rested-limb variance
    Sigma_p0 (Noel et al. 2018: 0.34-0.44 with no touch): Sigma_v = Sigma_p0 (1 - w0) / w0, so w = w0 while
    Sigma_p = Sigma_p0 and grows toward 1 as proprioception fades (:func:`felt_variance_step`).

    Parameters
    ----------
    felt_variance, base_variance : array_like, (B,)
        Sigma_p(t) and Sigma_p0, deg^2.
    base_weight : array_like, (B,)
        w0, in (0, 1].

    Returns
    -------
    ndarray, (B,)
        w, in (0, 1].
    """
    base_weight = np.asarray(base_weight, float)
    seen_variance = np.asarray(base_variance, float) * (1.0 - base_weight) / base_weight
    felt = np.asarray(felt_variance, float)
    return felt / (felt + seen_variance)



def belief_rate(s_p, realignment, mu, proprioceptive_variance):
    """mu_dot = (s_p + b - mu) / Sigma_p, (B, 2): the belief follows the realigned proprioception.

    The free-energy gradient of one Gaussian observation of the joint angles, the sensed s_p recalibrated by b
    (the paper's eq. 6 proprioceptive term), so mu settles at s_p + b: the perceived arm is the
    proprioceptive belief plus the realignment. The seen pose reaches mu only through b (counted once).

    Parameters
    ----------
    s_p, realignment, mu : array_like, (B, 2)
        deg.
    proprioceptive_variance : array_like, (B,)
        Sigma_p, deg^2 (read as 1/s, as in the paper's brain).

    Returns
    -------
    ndarray, (B, 2)
        deg/s.
    """
    return (np.asarray(s_p, float) + realignment - mu) / np.asarray(proprioceptive_variance, float)[:, None]



def free_energy(s_p, realignment, mu, proprioceptive_variance):
    """F = sum (s_p + b - mu)^2 / (2 Sigma_p), (B,): minus its gradient in mu is :func:`belief_rate`.

    Parameters
    ----------
    s_p, realignment, mu : array_like, (B, 2)
        deg; mu the step's start belief.
    proprioceptive_variance : array_like, (B,)
        Sigma_p, deg^2.

    Returns
    -------
    ndarray, (B,)
        Dimensionless.
    """
    gap = np.asarray(s_p, float) + realignment - mu
    return (gap ** 2).sum(axis=1) / (2.0 * np.asarray(proprioceptive_variance, float))
