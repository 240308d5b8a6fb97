"""The causal model's inference of a common cause, over space and time, with persistence (docs/model.md).

gamma = p(C = 1 | evidence) is the belief that the seen arm and the felt arm are one. It has two parts:
- a hidden two-state Markov state C_t (one cause / two causes) whose belief gamma_timing is carried
  from step to step by the chain's forward prediction (:func:`hazard_predict`) and updated at each
  visuo-tactile event pair by the likelihood ratio of the perceived delay (:func:`timing_likelihood_ratio`);
- the seen-felt discrepancy in body space, a static feature of the scene, counted once per step on
  top of it (:func:`spatial_likelihood_ratio`), not accumulated: re-seeing the same rubber arm is not
  new evidence.
gamma = :func:`posterior` (gamma_timing, spatial ratio). All functions are vectorised over the batch B.
"""
from __future__ import annotations

import numpy as np


def posterior(prior, likelihood_ratio):
    """Bayes' rule for two hypotheses: p1 = prior LR / (prior LR + 1 - prior), (B,).

    The first case of the paper's eq. 9 written with the ratio LR = p(data | C1) / p(data | C2).
    An infinite ratio gives 1, a zero ratio 0 (prior 0 or 1 stays).

    Parameters
    ----------
    prior : array_like, (B,)
        p(C1) before the data, in [0, 1].
    likelihood_ratio : array_like, (B,)
        LR >= 0, may be inf.

    Returns
    -------
    ndarray, (B,)
        p(C1 | data), in [0, 1].
    """
    prior, ratio = np.asarray(prior, float), np.asarray(likelihood_ratio, float)
    with np.errstate(invalid="ignore", over="ignore"):
        value = prior * ratio / (prior * ratio + (1.0 - prior))
    return np.where(np.isinf(ratio), np.where(prior > 0, 1.0, 0.0), np.where(np.isnan(value), prior, value))


def hazard_predict(gamma, prior, switching_time, step):
    """Forward prediction of a two-state continuous-time Markov chain over one step, (B,).

    With switching rates k_on (two causes -> one) and k_off (one -> two), stationary probability
    prior = k_on / (k_on + k_off) and relaxation time switching_time = 1 / (k_on + k_off), the
    probability of state 1 obeys dp/dt = k_on (1 - p) - k_off p, solved exactly over ``step``:
        p(t + h) = prior + (p(t) - prior) exp(-h / switching_time).
    This is the prediction step of the HMM forward algorithm with the hazard-rate transition
    (Rabiner 1989, Proc. IEEE 77:257; the hazard formulation as in Glaze, Kable & Gold 2015, eLife 4:e08825).

    Parameters
    ----------
    gamma, prior : array_like, (B,)
        p(state 1) now, and the chain's stationary probability; in [0, 1].
    switching_time : array_like, (B,)
        1 / (k_on + k_off), s.
    step : float
        h, s.

    Returns
    -------
    ndarray, (B,)
        p(state 1) after the step.
    """
    return prior + (np.asarray(gamma, float) - prior) * np.exp(-step / np.asarray(switching_time, float))


def timing_likelihood_ratio(perceived_delay, sync_sd, timing_noise_sd, async_density):
    """p(perceived delay | C1) / p(perceived delay | C2), (B,): the paper's eq. 8 with perceptual noise.

    Under one cause the true delay is N(0, sync_sd^2) (paper eq. 8) and is perceived with independent
    noise N(0, timing_noise_sd^2), so the perceived delay is N(0, sync_sd^2 + timing_noise_sd^2)
    (scipy's density); under two causes it is uniform with density ``async_density`` (the paper's p2).

    Parameters
    ----------
    perceived_delay : array_like, (B,)
        t_v - t_t plus the perceptual noise, s.
    sync_sd, timing_noise_sd : array_like, (B,)
        s.
    async_density : array_like, (B,)
        1/s.

    Returns
    -------
    ndarray, (B,)
        The ratio, >= 0.
    """
    scale = np.sqrt(np.asarray(sync_sd, float) ** 2 + np.asarray(timing_noise_sd, float) ** 2)
    from scipy.stats import norm  # here, not at the top: a refused command never pays for scipy.stats

    return norm.pdf(perceived_delay, loc=0.0, scale=scale) / async_density


def spatial_likelihood_ratio(seen_pose, seen_variance, felt_pose, proprioceptive_variance, coupling_sd,
                             workspace_mean, workspace_sd):
    """p(x_v | x_p, C1) / p(x_v | C2) of the seen pose x_v given the felt pose x_p, (B,), joint by joint.

    Koerding et al. 2007 (PLoS ONE 2:e943) as Samad, Chung & Shams 2015 (PLoS ONE 10:e0117178) apply it
    to the seen and the felt hand. One cause: x_v - x_p is Gaussian with the two senses' variances,
    the encoder's ``seen_variance`` and ``proprioceptive_variance``, plus ``coupling_sd``^2, how far a
    seen hand may lie from the felt one and still be it (a coupling prior, Ernst 2006; its width from
    peripersonal space, Litwin 2020). Two causes: x_v is anywhere in the arm's workspace, a broad
    Gaussian N(workspace_mean, workspace_sd^2). Densities from scipy.stats.norm; the product over the
    two joints (independent by assumption).

    Parameters
    ----------
    seen_pose, seen_variance, felt_pose : array_like, (B, 2)
        x_v (deg), Sigma_x (deg^2), x_p = s_p (deg).
    proprioceptive_variance : array_like, (B,)
        Sigma_p, deg^2.
    coupling_sd, workspace_mean, workspace_sd : array_like, (B, 2)
        deg.

    Returns
    -------
    ndarray, (B,)
        The ratio, >= 0.
    """
    common_sd = np.sqrt(np.asarray(seen_variance, float) + np.asarray(proprioceptive_variance, float)[:, None]
                        + np.asarray(coupling_sd, float) ** 2)
    from scipy.stats import norm

    one = norm.logpdf(seen_pose, loc=felt_pose, scale=common_sd).sum(axis=1)
    two = norm.logpdf(seen_pose, loc=workspace_mean, scale=workspace_sd).sum(axis=1)
    return np.exp(one - two)


def participants(seeds, medians: dict, log_sds: dict, prior_concentration):
    """Each trial's participant: the parameters drawn from the population, (B,) each, seeded per trial.

    timing_noise_sd, switching_time and coupling_scale are log-normal around their medians
    (median x exp(N(0, log_sd^2))); common_cause_prior is Beta(prior k, (1 - prior) k), k =
    ``prior_concentration`` (its mean the median given). A generator per trial from
    numpy's SeedSequence of (seed, 1), so the draws never share a stream with the stimulus' delays.

    Parameters
    ----------
    seeds : array_like of int, (B,)
        One per trial.
    medians : dict of ndarray, (B,) each
        ``common_cause_prior``, ``switching_time`` (s), ``timing_noise_sd`` (s).
    log_sds : dict of float or ndarray
        The sd of the log of ``timing_noise_sd``, ``switching_time`` and ``coupling_scale``.
    prior_concentration : array_like, (B,)
        k.

    Returns
    -------
    values : dict of ndarray, (B,) each
        ``timing_noise_sd``, ``switching_time``, ``coupling_scale`` (1), ``common_cause_prior``.
    generators : list of numpy.random.Generator, B
        They go on to draw each trial's timing noise.
    """
    generators = [np.random.default_rng([int(seed), 1]) for seed in seeds]
    draws = np.array([g.standard_normal(3) for g in generators]).reshape(len(generators), 3)
    prior = medians["common_cause_prior"]
    betas = np.array([g.beta(p * k, (1.0 - p) * k) for g, p, k in zip(generators, prior, prior_concentration)])
    values = {
        "timing_noise_sd": medians["timing_noise_sd"] * np.exp(log_sds["timing_noise_sd"] * draws[:, 0]),
        "switching_time": medians["switching_time"] * np.exp(log_sds["switching_time"] * draws[:, 1]),
        "coupling_scale": np.exp(log_sds["coupling_scale"] * draws[:, 2]),
        "common_cause_prior": betas,
    }
    return values, generators
