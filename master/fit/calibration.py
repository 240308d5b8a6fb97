"""Calibration of a posterior on held-out simulated participants whose parameters are known.

- Simulation-based calibration (Talts, Betancourt, Simpson, Vehtari & Gelman 2018, arXiv:1804.06788): for a
  calibrated posterior, the rank of the true value among L posterior samples is uniform on {0, ..., L}.
  Ranks are binned and tested against uniformity with Pearson's chi-square (scipy.stats.chisquare) and, on
  the ranks scaled to (0, 1), with a Kolmogorov-Smirnov test (scipy.stats.kstest). The fit's verdict takes
  these 2P tests as one family, with Bonferroni's correction.
- Coverage: the share of true values inside the central 50 % and 90 % posterior intervals, read off the
  ranks (:func:`coverage`); a calibrated posterior covers them at exactly these rates.
- Recovery: Pearson's correlation between the true values and the posterior medians.
"""
from __future__ import annotations

import numpy as np

LEVELS = (0.5, 0.9)
FAMILY_ALPHA = 0.05  # the family-wise error rate of the rank tests' verdict


def sbc_ranks(samples: np.ndarray, truths: np.ndarray) -> np.ndarray:
    """Talts et al. 2018, Algorithm 1: per participant and parameter, how many of the L posterior samples lie
    below the true value. samples: (participants, L, parameters); truths: (participants, parameters).
    Returns integer ranks in {0, ..., L}, (participants, parameters)."""
    return (np.asarray(samples) < np.asarray(truths)[:, None, :]).sum(axis=1)


def rank_bins(samples_per_participant: int, participants: int) -> int:
    """Bins of the rank histogram: a divisor of the L + 1 rank values, with at least 5 participants expected
    per bin (the chi-square test's usual condition) and at most 20 bins."""
    values = samples_per_participant + 1
    for bins in range(min(20, values), 0, -1):
        if values % bins == 0 and participants / bins >= 5:
            return bins
    return 1


def rank_histogram(ranks: np.ndarray, samples_per_participant: int, bins: int) -> np.ndarray:
    """(bins, parameters) counts of the ranks, each bin holding (L + 1) / bins consecutive rank values."""
    width = (samples_per_participant + 1) // bins
    return np.stack([np.bincount(column // width, minlength=bins) for column in np.asarray(ranks).T], axis=1)


def uniformity(ranks: np.ndarray, samples_per_participant: int) -> dict[str, np.ndarray]:
    """Per parameter: the chi-square test of the rank histogram against the uniform (p-value, statistic, bins)
    and the Kolmogorov-Smirnov test of the ranks, scaled to (0, 1) as (rank + 1/2) / (L + 1), against U(0, 1)."""
    from scipy import stats

    ranks = np.asarray(ranks)
    bins = rank_bins(samples_per_participant, len(ranks))
    counts = rank_histogram(ranks, samples_per_participant, bins)
    chi = [stats.chisquare(column) if bins > 1 else (np.nan, np.nan) for column in counts.T]
    scaled = (ranks + 0.5) / (samples_per_participant + 1)
    ks = [stats.kstest(column, "uniform") for column in scaled.T]
    return {"bins": bins, "counts": counts, "chisquare": np.array([c[0] for c in chi]),
            "chisquare_p": np.array([c[1] for c in chi]), "ks": np.array([k.statistic for k in ks]),
            "ks_p": np.array([k.pvalue for k in ks])}


def rank_tests_verdict(chisquare_p: np.ndarray, ks_p: np.ndarray, alpha: float = FAMILY_ALPHA) -> dict:
    """The SBC rank tests of every parameter (its chi-square and KS p-values) judged as one family: rejected iff
    some p-value is below alpha / m, m the number of tests (Bonferroni's correction, Dunn 1961, JASA 56:52: a
    family-wise error rate of at most alpha whatever the tests' dependence; Holm's 1979 step-down rejects some
    test exactly when this does). Judged one by one at alpha, m independent tests would fail a calibrated
    posterior with probability 1 - (1 - alpha)^m. A chi-square test without bins (NaN) is not counted.

    Returns tests (m), alpha, threshold (alpha / m), smallest_p and rejected."""
    p = np.concatenate([np.asarray(chisquare_p, float), np.asarray(ks_p, float)])
    p = p[np.isfinite(p)]
    smallest = float(p.min())
    return {"tests": len(p), "alpha": alpha, "threshold": alpha / len(p), "smallest_p": smallest,
            "rejected": smallest < alpha / len(p)}


def verdict_words(verdict: dict) -> str:
    """:func:`rank_tests_verdict` in words, for the command's output and the results table."""
    return (f"{'rejected' if verdict['rejected'] else 'not rejected'}: smallest p {verdict['smallest_p']:.3f} "
            f"{'<' if verdict['rejected'] else '≥'} {verdict['alpha']:g}/{verdict['tests']} = {verdict['threshold']:.4f}")


def central_interval(samples: np.ndarray, level: float, axis: int = -2) -> tuple[np.ndarray, np.ndarray]:
    """The central ``level`` interval of the samples along ``axis``: their (1 - level)/2 and (1 + level)/2
    quantiles (numpy's linear interpolation)."""
    return (np.quantile(samples, (1 - level) / 2, axis=axis), np.quantile(samples, (1 + level) / 2, axis=axis))


def coverage(samples: np.ndarray, truths: np.ndarray, level: float) -> np.ndarray:
    """Per parameter, the share of participants whose true value lies inside the posterior's central ``level``
    interval, read off the SBC ranks: inside when at least k of the L samples lie below it and at least k
    above, k = floor((L + 1)(1 - level) / 2), i.e. between the k-th smallest and the k-th largest sample. A
    calibrated posterior's rank is uniform on {0, ..., L}, so this interval covers exactly (L + 1 - 2k) / (L + 1)
    of the truths: ``level`` itself when (L + 1)(1 - level) / 2 is whole (L = 99 for 50 % and 90 %). The
    samples' own quantiles would cover less: between numpy's 5 % and 95 % quantiles of 99 samples lie
    (94.1 - 5.9) / 100 = 88.2 % of a calibrated posterior's truths.
    samples: (participants, L, parameters); truths: (participants, parameters)."""
    return rank_coverage(sbc_ranks(samples, truths), np.shape(samples)[1], level)


def rank_coverage(ranks: np.ndarray, samples_per_participant: int, level: float) -> np.ndarray:
    """:func:`coverage` from the ranks themselves, (participants, parameters), of L = samples_per_participant."""
    k = int(np.floor((samples_per_participant + 1) * (1 - level) / 2 + 1e-9))
    return ((ranks >= k) & (ranks <= samples_per_participant - k)).mean(axis=0)


def recovery(samples: np.ndarray, truths: np.ndarray) -> dict[str, np.ndarray]:
    """Per parameter: the posterior medians, Pearson's correlation with the true values, and the posterior sd
    relative to the prior's (the held-out truths' sd): near 1, the data told nothing about the parameter."""
    medians = np.median(samples, axis=1)
    correlation = np.array([np.corrcoef(truths[:, d], medians[:, d])[0, 1] for d in range(truths.shape[1])])
    contraction = np.mean(np.std(samples, axis=1), axis=0) / np.std(truths, axis=0)
    return {"medians": medians, "correlation": correlation, "sd_ratio": contraction}


def calibrate(samples: np.ndarray, truths: np.ndarray) -> dict:
    """Everything above for held-out participants: samples (participants, L, parameters) and truths, both in
    the same space (the inference space: ranks, coverage and correlation are those of the inference space's
    values; ranks and coverage are the same in the parameters' own units, a monotone map of it)."""
    samples, truths = np.asarray(samples), np.asarray(truths)
    ranks = sbc_ranks(samples, truths)
    tests = uniformity(ranks, samples.shape[1])
    return {"ranks": ranks, "uniformity": tests, "verdict": rank_tests_verdict(tests["chisquare_p"], tests["ks_p"]),
            "coverage": {level: rank_coverage(ranks, samples.shape[1], level) for level in LEVELS},
            "recovery": recovery(samples, truths), "participants": len(truths), "samples": samples.shape[1]}
