"""The ownership model's equations: ownership as accumulated timing evidence, drift as a slow realignment.

One function per equation, each vectorised over the batch of B trials (docs/model.md, "The ownership model"):

- :func:`asynchrony_log_likelihood_ratio`: the evidence of one touch's timing, log p(Δ' | one cause) / p(Δ' | two),
  under ownership's visuo-tactile window or the coupling's visuo-proprioceptive one;
- :func:`ownership_belief`: ownership from the touches' timing and, counted once, the seen hand's place;
- :func:`counter_evidence_step` and :func:`coupling_belief`: the slow, leaky accumulation of the touches' evidence
  about visuo-proprioceptive unity, and the coupling it leaves;
- :func:`hand_separation` and :func:`spatial_log_likelihood_ratio`: the evidence of its place, how far the seen
  touch lies from the felt one (:func:`peripersonal_sd_from_boundary` derives the spread from where it is neutral);
- between touches the common-cause state relaxes to its prior as a two-state Markov chain, and at a touch
  Bayes' rule adds the touch's evidence to its log odds: the causal model's
  :func:`~rhi.components.brain.body_inference.hazard_predict` (switching_time = 1 / switching rate) and
  :func:`~rhi.components.brain.body_inference.posterior` (likelihood ratio = exp of the log ratio), reused;
- :func:`ownership_onset`: the first time ownership gamma reaches 1/2;
- :func:`felt_variance_step` and :func:`visual_weight`: proprioception fading at rest, and the seen hand's weight;
- :func:`realignment_target` and :func:`realignment_step`: the slow realignment b and its exact step;
- :func:`belief_rate` and :func:`free_energy`: the belief follows the realigned proprioception s_p + b.
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
    (:func:`counter_evidence_step`). Under two causes the seen and
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


def counter_evidence_step(evidence, leak_rate, step):
    """The accumulated evidence about visuo-proprioceptive unity between touches: C <- C exp(-kappa h), (B,), nats.

    Rohde, Di Luca & Ernst 2011 (PLoS ONE 6:e21659, Discussion) explain their data so: evidence against the
    "unity assumption" of the seen and the felt hand builds up the longer asynchronous stroking goes on, and
    interruptions interrupt that accumulation. C is the sum of the touches' log likelihood ratios under the
    coupling's window (:func:`asynchrony_log_likelihood_ratio` with the coupling's sd: wide, so each touch says
    little and the sum grows over many), forgotten at the leak rate kappa: over a pause of length tau the
    accumulation is discounted by exp(-kappa tau), and within continuous stroking it levels off where each touch
    adds what the leak takes. Exact over the step; kappa a free rate (fitted).

    Parameters
    ----------
    evidence : array_like, (B,)
        C, nats (negative: against unity).
    leak_rate : array_like, (B,)
        kappa, 1/s (>= 0).
    step : float
        h, s.

    Returns
    -------
    ndarray, (B,)
        C after the step, nats.
    """
    return np.asarray(evidence, float) * np.exp(-np.asarray(leak_rate, float) * step)


def coupling_belief(prior, place_evidence, counter_evidence):
    """The coupling rho = logistic(logit rho0 + l_s + C), (B,): the belief that the seen hand and the felt one are
    one (visuo-proprioceptive unity).

    Bayes' rule in log odds (the paper's eq. 8 in its odds form): the prior rho0 of a hand seen at the place
    where a touch's place is neutral (:func:`peripersonal_sd_from_boundary`), plus the evidence of the seen hand's
    place, counted once (a static property of the scene, re-seeing it is no new evidence: l_s of
    :func:`spatial_log_likelihood_ratio`, 0 while no hand is seen), plus the touches' accumulated evidence C
    (:func:`counter_evidence_step`).

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


def realignment_target(seen_pose, felt_pose, weight, coupling, seen=1.0):
    """Where the realignment b settles: b* = v w rho (x_v - s_p), (B, 2), deg.

    w is the fraction of the way a seen hand pulls the felt one (Noel et al. 2018, Sci Rep 8:15819: 30-40 %,
    coupling weight 0.34-0.44, measured with no touch); rho the coupling belief, the probability that the
    seen hand lies where the felt one is (docs/model.md); v is 1 while a hand is seen, 0 while none is
    (:func:`seen_hand`). Joint angles: a fraction of the way is the same fraction in hand space to first order
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


def seen_hand(arm_visible):
    """v = 1 where a hand is seen, 0 where none is, (B,): the scene's declaration of the rubber arm's visibility.

    A seen object pulls the felt hand, and can be owned, only if it looks like a hand: with a wooden block in
    its place there is no illusion and no drift (Tsakiris & Haggard 2005, JEP:HPP 31:80), and with nothing in
    view there is nothing to pull toward. So while no hand is seen, the seen pose (what a pose encoder reads
    from an image without an arm is no arm's pose) moves nothing: the realignment neither moves toward it nor
    away (:func:`realignment_step` at rate k v, a recalibration kept until new evidence) and a seen touch is
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
