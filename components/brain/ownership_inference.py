"""The ownership model's beliefs: ownership and the coupling from the touches' timing and the seen hand's place.

One function per equation, each vectorised over the batch of B trials (docs/model.md, "The ownership model"; the
drift they drive, a slow realignment, is :mod:`rhi.components.brain.realignment`'s):

- :func:`asynchrony_log_likelihood_ratio`: the evidence of one touch's timing, log p(Δ' | one cause) / p(Δ' | two),
  under ownership's visuo-tactile window or the coupling's visuo-proprioceptive one;
- :func:`ownership_belief`: ownership from the touches' timing and, counted once, the seen hand's place;
- :func:`relaxation_step` (toward 0) and :func:`coupling_belief`: the slow, leaky accumulation of the touches'
  evidence about visuo-proprioceptive unity, and the coupling it leaves;
- :func:`hand_separation` and :func:`spatial_log_likelihood_ratio`: the evidence of its place, how far the seen
  touch lies from the felt one (:func:`peripersonal_sd_from_boundary` derives the spread from where it is neutral);
- between touches the common-cause state relaxes to its prior as a two-state Markov chain, and at a touch
  Bayes' rule adds the touch's evidence to its log odds: the causal model's
  :func:`~rhi.components.brain.body_inference.hazard_predict` (switching_time = 1 / switching rate) and
  :func:`~rhi.components.brain.body_inference.posterior` (likelihood ratio = exp of the log ratio), reused;
- :func:`ownership_onset`: the first time ownership gamma reaches 1/2;
- :func:`seen_hand`: whether a hand is seen, which gates the touches' evidence and the realignment;
- :func:`relaxation_step`: the exact step of a state relaxing at its own rate, the counter-evidence's leak and the
  realignment's approach to its target.
"""
from __future__ import annotations

import math

import numpy as np

def asynchrony_log_likelihood_ratio(perceived_asynchrony, timing_sd, stroke_period):
    """The evidence of one touch: log N(Δ'; 0, sigma_t^2) - log(1/T), (B,), in nats.

    Under one cause the seen and the felt stroke are the same event, so their perceived asynchrony Δ' is 0
    plus the perceptual noise, N(0, sigma_t^2): the paper's eq. 8 (Rood et al. 2020, p1 with sd 0.2 s, for
    strokes; the illusion survives delays of the seen stroke up to about 300 ms, Shimada, Fukuda & Hiraki
    2009, PLoS ONE 4:e6185). The same form with a wider sd is the coupling's visuo-proprioceptive window
    (:func:`relaxation_step` toward 0). Under two causes the seen and
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


def ownership_belief(timing_belief, place_evidence):
    """Ownership gamma = logistic(logit gamma_t + v l_s), (B,): the touches' timing belief with the seen hand's place.

    Visual capture before any touch: a hand-like object seen where one's hand could be is taken, to a degree, as
    one's own already (Samad, Chung & Shams 2015, PLoS ONE 10:e0117178: most participants rated the rubber hand
    as theirs before the first stroke). The seen hand's place is evidence about one cause (the log ratio l_s of
    :func:`spatial_log_likelihood_ratio`, 0 while no hand is seen), a static property of the scene: counted
    once, on top of the chain gamma_t that accumulates the touches' timing (re-seeing the same hand is no new
    evidence; the causal model's rule). So the prior of ownership depends on where the hand is seen: with
    gamma_t at the paper's gamma0 = 0.01, 0.14 for a hand seen where the felt one is, 0.08 at 15 cm, gamma0 at
    the boundary D (30 cm), less beyond.

    Parameters
    ----------
    timing_belief : array_like, (B,)
        gamma_t, in [0, 1].
    place_evidence : array_like, (B,)
        v l_s, nats.

    Returns
    -------
    ndarray, (B,)
        gamma, in [0, 1].
    """
    gamma = np.clip(np.asarray(timing_belief, float), 1e-300, 1.0 - 1e-16)
    odds = np.log(gamma / (1.0 - gamma)) + np.asarray(place_evidence, float)
    return 0.5 * (1.0 + np.tanh(0.5 * odds))


def relaxation_step(value, target, rate, step):
    """dx/dt = r (x* - x) solved exactly over a step with x* held: x <- x* + (x - x*) exp(-r h), (B,) or (B, 2).

    Two of the ownership model's slow states relax so, each at its own rate r, exactly over the step:

    - the counter-evidence C toward 0 at the leak kappa between touches (x* = 0). Rohde, Di Luca & Ernst 2011
      (PLoS ONE 6:e21659, Discussion) explain their data so: evidence against the "unity assumption" of the seen
      and the felt hand builds up the longer asynchronous stroking goes on, and interruptions interrupt that
      accumulation. C is the sum of the touches' log likelihood ratios under the coupling's window
      (:func:`asynchrony_log_likelihood_ratio` with the coupling's sd: wide, so each touch says little and the
      sum grows over many), forgotten at kappa: over a pause of length tau the accumulation is discounted by
      exp(-kappa tau), and within continuous stroking it levels off where each touch adds what the leak takes;
      kappa a free rate (fitted).
    - the realignment b toward b* (:func:`rhi.components.brain.realignment.realignment_target`) at rate k v: a
      slow visuo-proprioceptive realignment (recalibration) that builds over tens of seconds and decays only as
      its own state does (Machulla et al. 2012: recalibration persists until counter-evidence); k a free rate.

    Parameters
    ----------
    value, target : array_like, (B,) or (B, 2)
        x and x* (C in nats and 0; b and b* in deg); ``target`` broadcast against ``value``.
    rate : array_like, (B,)
        r, 1/s (>= 0; 0: x held).
    step : float
        h, s.

    Returns
    -------
    ndarray, the shape of ``value``
        x after the step.
    """
    value, target = np.asarray(value, float), np.asarray(target, float)
    decay = np.exp(-np.asarray(rate, float) * step)
    decay = decay.reshape(decay.shape + (1,) * (value.ndim - decay.ndim))  # one rate per trial, over its joints
    return target + (value - target) * decay


def coupling_belief(prior, place_evidence, counter_evidence):
    """The coupling rho = logistic(logit rho0 + l_s + C), (B,): the belief that the seen hand and the felt one are
    one (visuo-proprioceptive unity).

    Bayes' rule in log odds (the paper's eq. 8 in its odds form): the prior rho0 of a hand seen at the place
    where a touch's place is neutral (:func:`peripersonal_sd_from_boundary`), plus the evidence of the seen hand's
    place, counted once (a static property of the scene, re-seeing it is no new evidence: l_s of
    :func:`spatial_log_likelihood_ratio`, 0 while no hand is seen), plus the touches' accumulated evidence C
    (:func:`relaxation_step` toward 0).

    Parameters
    ----------
    prior : array_like, (B,)
        rho0, in (0, 1).
    place_evidence, counter_evidence : array_like, (B,)
        l_s and C, nats.

    Returns
    -------
    ndarray, (B,)
        rho, in [0, 1].
    """
    prior = np.asarray(prior, float)
    odds = np.log(prior / (1.0 - prior)) + np.asarray(place_evidence, float) + np.asarray(counter_evidence, float)
    return 0.5 * (1.0 + np.tanh(0.5 * odds))  # the logistic, without overflow at large |odds|


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


def seen_hand(arm_visible):
    """v = 1 where a hand is seen, 0 where none is, (B,): the scene's declaration of the rubber arm's visibility.

    A seen object pulls the felt hand, and can be owned, only if it looks like a hand: with a wooden block in
    its place there is no illusion and no drift (Tsakiris & Haggard 2005, JEP:HPP 31:80), and with nothing in
    view there is nothing to pull toward. So while no hand is seen, the seen pose (what a pose encoder reads
    from an image without an arm is no arm's pose) moves nothing: the realignment neither moves toward it nor
    away (:func:`relaxation_step` at rate k v, a recalibration kept until new evidence) and a seen touch is
    not a touch of a seen hand (no visuo-tactile evidence).

    Parameters
    ----------
    arm_visible : array_like, (B,)
        The scene's signal, 1 while the rubber arm is in view, 0 while not.

    Returns
    -------
    ndarray, (B,)
        1.0 or 0.0.
    """
    return (np.asarray(arm_visible, float) > 0.5).astype(float)
