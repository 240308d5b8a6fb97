"""The ownership model's equations: ownership as accumulated timing evidence, drift as a slow realignment.

One function per equation, each vectorised over the batch of B trials (docs/model.md, "The ownership model"):

- :func:`timing_sd_from_jnd`: the sd of a perceived visuo-tactile asynchrony from a temporal-order JND;
- :func:`asynchrony_log_likelihood_ratio`: the evidence of one touch's timing, log p(Δ' | one cause) / p(Δ' | two);
- :func:`hand_separation` and :func:`spatial_log_likelihood_ratio`: the evidence of its place, how far the seen
  touch lies from the felt one (:func:`peripersonal_sd_from_boundary` derives the spread from where it is neutral);
- between touches the common-cause state relaxes to its prior as a two-state Markov chain, and at a touch
  Bayes' rule adds the touch's evidence to its log odds: the causal model's
  :func:`~rhi.components.brain.body_inference.hazard_predict` (switching_time = 1 / switching rate) and
  :func:`~rhi.components.brain.body_inference.posterior` (likelihood ratio = exp of the log ratio), reused;
- :func:`ownership_onset`: the first time ownership gamma reaches 1/2;
- :func:`realignment_target` and :func:`realignment_step`: the slow realignment b and its exact step;
- :func:`belief_rate` and :func:`free_energy`: the belief follows the realigned proprioception s_p + b.
"""
from __future__ import annotations

import math

import numpy as np

QUARTILE_Z = 0.6744897501960817  # scipy.stats.norm.ppf(0.75): the 75 % point of the standard normal


def timing_sd_from_jnd(jnd):
    """sd of the perceived visuo-tactile asynchrony, sigma_t = JND / z_0.75, from a temporal-order JND.

    In a temporal-order judgement the probability of "vision first" at SOA s is the cumulative Gaussian
    Phi((s - PSS) / sigma_t), sigma_t the sd of the perceived asynchrony itself (one noisy difference per
    trial, no two-interval comparison, so no factor sqrt 2); the JND is half the 25-75 % interval,
    JND = z_0.75 sigma_t, z_0.75 = 0.6745. Machulla, Di Luca & Ernst 2016 (JEP:HPP) report visuo-tactile
    JNDs of 55-65 ms, so sigma_t = 82-96 ms.

    Parameters
    ----------
    jnd : array_like, (B,) or scalar
        The just-noticeable difference, s.

    Returns
    -------
    ndarray, same shape
        sigma_t, s.
    """
    return np.asarray(jnd, dtype=float) / QUARTILE_Z


def asynchrony_log_likelihood_ratio(perceived_asynchrony, timing_sd, stroke_period):
    """The evidence of one touch: log N(Δ'; 0, sigma_t^2) - log(1/T), (B,), in nats.

    Under one cause the seen and the felt stroke are the same event, so their perceived asynchrony Δ' is 0
    plus the perceptual noise, N(0, sigma_t^2) (:func:`timing_sd_from_jnd`). Under two causes the seen and
    the felt stroke are unrelated events of the same rhythm, so Δ' is uniform over one stroke period T,
    density 1/T, taken constant over the delays a pairing of events can give (the paper's eq. 8 treats its
    p2 so; with T = 2 s it is the paper's p2 = 0.5 /s). Densities from scipy.stats (norm.logpdf).

    Parameters
    ----------
    perceived_asynchrony : array_like, (B,)
        Δ' = t_v - t_t plus the perceptual noise, s.
    timing_sd : array_like, (B,)
        sigma_t, s.
    stroke_period : array_like, (B,)
        T, s.

    Returns
    -------
    ndarray, (B,)
        The log likelihood ratio, nats (positive: evidence for one cause).
    """
    from scipy.stats import norm  # here, not at the top: a refused command never pays for scipy.stats

    return norm.logpdf(perceived_asynchrony, loc=0.0, scale=timing_sd) + np.log(np.asarray(stroke_period, float))


def hand_separation(seen_pose, felt_pose, upper_arm, forearm):
    """The distance between the hands two poses of one arm put, (B,), m: the brain's body schema.

    Planar two-link forward kinematics from the shared shoulder: hand = U (cos s, sin s) + F (cos(s + e),
    sin(s + e)) for shoulder angle s and relative elbow angle e (the body's frame, docs/design.md); the
    shoulder's position cancels in the difference.

    Parameters
    ----------
    seen_pose, felt_pose : array_like, (B, 2)
        (shoulder, elbow), deg: x_v (the pose encoder's reading) and s_p (sensed).
    upper_arm, forearm : array_like, (B,)
        U and F, the segments' lengths, m.

    Returns
    -------
    ndarray, (B,)
        m.
    """
    def hand(pose):
        shoulder = np.radians(np.asarray(pose, float)[:, 0])
        forearm_angle = shoulder + np.radians(np.asarray(pose, float)[:, 1])
        return np.stack([upper_arm * np.cos(shoulder) + forearm * np.cos(forearm_angle),
                         upper_arm * np.sin(shoulder) + forearm * np.sin(forearm_angle)], axis=1)
    return np.hypot(*(hand(seen_pose) - hand(felt_pose)).T)


def spatial_log_likelihood_ratio(separation, peripersonal_sd, reach):
    """The evidence of one touch's place: log N2(d; 0, sigma_s^2 I) - log(1 / (pi L^2)), (B,), in nats.

    Under one cause the seen stroke is the felt one, seen within the felt hand's peripersonal space: its
    displacement d in the table's plane is an isotropic Gaussian of sd sigma_s per axis. Under two causes the
    seen stroke is on some other hand-like object anywhere within one arm's reach L of the felt hand, uniform
    over that disc (density 1 / (pi L^2)). So log ratio = log(L^2 / (2 sigma_s^2)) - |d|^2 / (2 sigma_s^2):
    positive near the hand, zero at the boundary (:func:`peripersonal_sd_from_boundary`), negative beyond.

    Parameters
    ----------
    separation : array_like, (B,)
        |d|, m (:func:`hand_separation`).
    peripersonal_sd, reach : array_like, (B,)
        sigma_s and L, m.

    Returns
    -------
    ndarray, (B,)
        The log likelihood ratio, nats (positive: evidence for one cause).
    """
    variance = np.asarray(peripersonal_sd, float) ** 2
    separation = np.asarray(separation, float)
    return np.log(np.asarray(reach, float) ** 2 / (2.0 * variance)) - separation ** 2 / (2.0 * variance)


def peripersonal_sd_from_boundary(boundary, reach):
    """sigma_s such that a touch seen ``boundary`` from the felt one carries no evidence of its place, m.

    Solves :func:`spatial_log_likelihood_ratio` = 0 at |d| = D: log(L^2 / (2 s^2)) = D^2 / (2 s^2). Its left
    side minus its right has one maximum, 2 log(L / D) - 1 at s = D / sqrt 2, so there are two roots when
    L > D sqrt(e) and none otherwise; this is the smaller, below D / sqrt 2: with the larger the
    common cause's spread would exceed the boundary itself, so that a seen hand beyond the space where it is
    still taken as one's own would be typical of one cause. Root-finding by scipy's brentq.

    Parameters
    ----------
    boundary, reach : float
        D and L, m (L > D sqrt(e)).

    Returns
    -------
    float
        sigma_s, m.
    """
    from scipy.optimize import brentq

    boundary, reach = float(boundary), float(reach)
    if not (0.0 < boundary and 2.0 * math.log(reach / boundary) > 1.0):
        raise ValueError(f"no peripersonal sd gives a neutral touch at {boundary:g} m within a reach of "
                         f"{reach:g} m (needs reach > boundary * sqrt(e))")

    def neutral(sd):
        return float(spatial_log_likelihood_ratio(boundary, sd, reach))
    return brentq(neutral, boundary * 1e-3, boundary / math.sqrt(2.0), xtol=1e-15, rtol=4 * np.finfo(float).eps)


def ownership_onset(onset, gamma, time, threshold=0.5):
    """The ownership onset: the first time gamma reaches the threshold, kept once set, (B,).

    The decision rule of Chancel, Ehrsson & Ma 2022 (eLife 11:e77221): the rubber hand is reported as one's
    own when the posterior of a common cause exceeds 1/2.

    Parameters
    ----------
    onset : array_like, (B,)
        The onset so far, s; NaN while gamma has not reached the threshold.
    gamma : array_like, (B,)
        Ownership at ``time``, in [0, 1].
    time : float
        s.
    threshold : float
        1/2 by the rule.

    Returns
    -------
    ndarray, (B,)
        s; NaN where gamma has never reached the threshold.
    """
    onset = np.asarray(onset, dtype=float)
    return np.where(np.isnan(onset) & (np.asarray(gamma) >= threshold), float(time), onset)


def realignment_target(seen_pose, felt_pose, weight, coupling):
    """Where the realignment b settles: b* = w rho (x_v - s_p), (B, 2), deg.

    w is the fraction of the way a seen hand pulls the felt one (Noel et al. 2018, Sci Rep 8:15819: 30-40 %,
    coupling weight 0.34-0.44, measured with no touch); rho the coupling belief, the probability that the
    seen hand lies where the felt one is (docs/model.md). Joint angles: a fraction of the way is the same
    fraction in hand space to first order (the arm's Jacobian is linear).

    Parameters
    ----------
    seen_pose, felt_pose : array_like, (B, 2)
        x_v (the pose encoder's reading of the image) and s_p (sensed), deg.
    weight, coupling : array_like, (B,)
        w and rho, 1.

    Returns
    -------
    ndarray, (B, 2)
        deg.
    """
    scale = np.asarray(weight, float) * np.asarray(coupling, float)
    return scale[:, None] * (np.asarray(seen_pose, float) - np.asarray(felt_pose, float))


def realignment_step(realignment, target, rate, step):
    """db/dt = k (b* - b) solved exactly over a step with b* held: b <- b* + (b - b*) exp(-k h), (B, 2).

    A slow visuo-proprioceptive realignment (recalibration) that builds over tens of seconds and decays only
    as its own state does (Machulla et al. 2012: recalibration persists until counter-evidence); k a free rate.

    Parameters
    ----------
    realignment, target : array_like, (B, 2)
        b and b*, deg.
    rate : array_like, (B,)
        k, 1/s (>= 0).
    step : float
        h, s.

    Returns
    -------
    ndarray, (B, 2)
        b after the step, deg.
    """
    target = np.asarray(target, dtype=float)
    decay = np.exp(-np.asarray(rate, float) * step)[:, None]
    return target + (np.asarray(realignment, float) - target) * decay


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
