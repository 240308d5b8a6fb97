"""Each statistic rhi fit reports (master/fit/calibration.py, calibration.csv and recovery.csv of
master/fit/report.py), against a hand computation on a small posterior made so that every rank is known.

24 held-out participants, L = 5 posterior samples of 2 parameters. Participant i's samples of parameter d are a
shuffled 0, 1, 2, 3, 7 (skewed: their mean is not their median), times a scale, plus a shift; its truth is placed
so that exactly a chosen number of samples lie below it (its SBC rank), one of them on a sample (a tie: a sample
equal to the truth is not below it). With
L + 1 = 6 rank values and 24 participants the rank histogram has 3 bins of 2 rank values (6 bins would expect
4 < 5 participants each). Each statistic is computed here from its definition (Talts et al. 2018; Pearson's
chi-square; the exact two-sided Kolmogorov-Smirnov distribution; Pearson's r), with scipy or by hand, not with
the module's helpers: an offset (rank + 1, or (rank + 1/2) / L), a tie counted as below, a bin of the wrong
width or a column of the wrong statistic changes a number below.
"""
import csv
import io
import statistics
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from rhi.master.fit.calibration import calibrate
from rhi.master.fit.report import calibration_csv, recovery_csv

L = 5
RANKS = np.array([  # the chosen SBC rank of each of 24 participants, per parameter: every value 0..5 used
    [0, 5], [1, 4], [2, 3], [3, 2], [4, 1], [5, 0], [0, 0], [1, 1], [2, 2], [3, 3], [4, 4], [5, 5],
    [2, 0], [2, 1], [3, 0], [3, 1], [1, 5], [0, 5], [4, 5], [5, 2], [1, 3], [4, 2], [0, 4], [5, 3]])
SCALES = (1.0, 3.0)
VALUES = np.array([0.0, 1.0, 2.0, 3.0, 7.0])  # one participant's samples, before scale and shift
TIE = (8, 0)  # participant 8's truth of parameter 0 equals one of its samples (rank 2: the samples 0 and 1 below)


def posterior():
    """(samples (24, L, 2), truths (24, 2)) with the ranks RANKS by construction."""
    rng = np.random.default_rng(7)
    count = len(RANKS)
    samples, truths = np.empty((count, L, 2)), np.empty((count, 2))
    for i in range(count):
        for d, scale in enumerate(SCALES):
            shift = 10.0 * i + d  # the truths vary across participants: the recovery's correlation is defined
            samples[i, :, d] = scale * rng.permutation(VALUES) + shift
            rank = RANKS[i, d]
            if (i, d) == TIE:  # on the sample just above the rank's: not below it
                value = VALUES[rank]
            else:  # half-way between the samples of ranks r - 1 and r (half a step beyond them at the ends)
                padded = np.concatenate([[VALUES[0] - 1.0], VALUES, [VALUES[-1] + 1.0]])
                value = padded[rank:rank + 2].mean()
            truths[i, d] = scale * value + shift
    return samples, truths


def test_the_posterior_is_made_as_said():
    samples, truths = posterior()
    below = [[sum(1 for s in samples[i, :, d] if s < truths[i, d]) for d in range(2)] for i in range(len(truths))]
    assert np.array_equal(below, RANKS)
    assert truths[TIE] in samples[TIE[0], :, TIE[1]]


def test_the_sbc_ranks_are_the_samples_strictly_below_the_truth():
    samples, truths = posterior()
    assert calibrate(samples, truths)["ranks"].tolist() == RANKS.tolist()


def test_the_chi_square_of_the_rank_histogram_by_hand():
    samples, truths = posterior()
    u = calibrate(samples, truths)["uniformity"]
    assert u["bins"] == 3
    for d in range(2):
        counts, _ = np.histogram(RANKS[:, d], bins=[0, 2, 4, 6])  # ranks {0, 1}, {2, 3}, {4, 5}
        assert u["counts"][:, d].tolist() == counts.tolist()
        expected = len(RANKS) / 3
        statistic = sum((o - expected) ** 2 / expected for o in counts)
        assert u["chisquare"][d] == pytest.approx(statistic, rel=1e-12)  # float rounding of a sum of 3 terms
        assert u["chisquare_p"][d] == pytest.approx(stats.chi2.sf(statistic, df=2), rel=1e-12)
    # the counts themselves: parameter 0 holds ranks 0, 1 eight times, 2, 3 eight, 4, 5 eight
    assert u["counts"][:, 0].tolist() == [8, 8, 8] and u["chisquare"][0] == 0.0 and u["chisquare_p"][0] == 1.0


def ks_by_hand(points: np.ndarray) -> float:
    """The two-sided Kolmogorov-Smirnov statistic of ``points`` against U(0, 1): the largest gap between the
    empirical distribution function (just after and just before each point) and the uniform's."""
    ordered, n = sorted(points), len(points)
    return max(max((k + 1) / n - x, x - k / n) for k, x in enumerate(ordered))


def test_the_ks_test_of_the_ranks_scaled_to_the_middle_of_their_bins():
    """Rank r of L = 5 is scaled to (r + 1/2) / 6: 1/12, 3/12, ..., 11/12, the middles of 6 equal bins of (0, 1)."""
    samples, truths = posterior()
    u = calibrate(samples, truths)["uniformity"]
    for d in range(2):
        scaled = (RANKS[:, d] + 0.5) / (L + 1)
        statistic = ks_by_hand(scaled)
        assert u["ks"][d] == pytest.approx(statistic, rel=1e-12)
        # scipy's exact distribution of the statistic for n = 24 (kstest's method for a sample this small)
        assert u["ks_p"][d] == pytest.approx(stats.kstwo.sf(statistic, len(scaled)), rel=1e-9)
        for wrong in (RANKS[:, d] / L, (RANKS[:, d] + 1) / (L + 1), RANKS[:, d] / (L + 1)):  # offsets a bug could make
            assert abs(ks_by_hand(wrong) - statistic) > 1e-3
    # parameter 0: every rank 4 times; the scaled ranks' largest gap is 1/12 (each point half a bin from its edges)
    assert u["ks"][0] == pytest.approx(1 / 12, rel=1e-12)


def test_the_coverage_counts_truths_with_k_samples_below_and_k_not_below():
    """k = floor((L + 1)(1 - level) / 2): at 50 %, floor(1.5) = 1, so a truth is inside when at least one sample
    is below it and at least one is not (rank 1 to 4); at 90 %, k = floor(0.3) = 0: every truth."""
    samples, truths = posterior()
    result = calibrate(samples, truths)
    for d in range(2):
        inside = [sum(s < t for s in samples[i, :, d]) >= 1 and sum(s >= t for s in samples[i, :, d]) >= 1
                  for i, t in enumerate(truths[:, d])]
        assert result["coverage"][0.5][d] == pytest.approx(sum(inside) / len(inside), abs=0)
    assert result["coverage"][0.5].tolist() == [16 / 24, 15 / 24]  # ranks 1-4: 16 of parameter 0's, 15 of 1's
    assert result["coverage"][0.9].tolist() == [1.0, 1.0]


def test_the_recovery_correlation_and_the_sd_ratio_by_hand():
    samples, truths = posterior()
    recovery = calibrate(samples, truths)["recovery"]
    for d, scale in enumerate(SCALES):
        medians = [statistics.median(samples[i, :, d]) for i in range(len(truths))]
        assert recovery["medians"][:, d].tolist() == medians
        assert medians == [scale * 2 + 10.0 * i + d for i in range(len(truths))]  # the middle of VALUES, scaled
        r = stats.pearsonr(truths[:, d], medians).statistic
        assert recovery["correlation"][d] == pytest.approx(r, rel=1e-12)
        spread = statistics.mean(statistics.pstdev(samples[i, :, d]) for i in range(len(truths)))
        # the population sd of VALUES: mean 2.6, squared deviations 6.76 + 2.56 + 0.36 + 0.16 + 19.36 = 29.2, / 5
        assert spread == pytest.approx(scale * np.sqrt(29.2 / 5), rel=1e-12)
        assert recovery["sd_ratio"][d] == pytest.approx(spread / statistics.pstdev(truths[:, d]), rel=1e-12)


def test_calibration_csv_carries_each_statistic_in_its_column():
    samples, truths = posterior()
    result = calibrate(samples, truths)
    rows = list(csv.DictReader(io.StringIO(calibration_csv([SimpleNamespace(key="a"), SimpleNamespace(key="b")],
                                                           result))))
    assert [row["parameter"] for row in rows] == ["a", "b"]
    for d, row in enumerate(rows):
        counts, _ = np.histogram(RANKS[:, d], bins=[0, 2, 4, 6])
        chi = stats.chisquare(counts)
        ks = stats.kstest((RANKS[:, d] + 0.5) / (L + 1), "uniform")
        truth = {"held_out": 24, "sbc_bins": 3, "correlation": stats.pearsonr(truths[:, d], np.median(samples[:, :, d],
                 axis=1)).statistic, "coverage_50": np.mean((RANKS[:, d] >= 1) & (RANKS[:, d] <= 4)),
                 "coverage_90": 1.0, "sbc_chisquare": chi.statistic, "sbc_chisquare_p": chi.pvalue,
                 "sbc_ks": ks.statistic, "sbc_ks_p": ks.pvalue}
        for column, value in truth.items():
            # the tables write 6 significant digits (rhi.master.outputs.tables.number, %.6g): a relative 5e-6
            assert float(row[column]) == pytest.approx(value, rel=5e-6, abs=1e-12), column


def test_recovery_csv_rows_hold_truth_median_interval_and_rank():
    samples, truths = posterior()
    ranks = calibrate(samples, truths)["ranks"]
    rows = list(csv.DictReader(io.StringIO(recovery_csv([SimpleNamespace(key="a"), SimpleNamespace(key="b")],
                                                        truths, samples, ranks))))
    assert len(rows) == 24
    for i, row in enumerate(rows):
        for d, key in enumerate(("a", "b")):
            ordered = sorted(samples[i, :, d])  # numpy's linear quantile of 5 values: 5 % lies at 0.2 of the way
            low = ordered[0] + 0.2 * (ordered[1] - ordered[0])  # from the 1st to the 2nd, 95 % at 0.8 from 4th to 5th
            high = ordered[3] + 0.8 * (ordered[4] - ordered[3])
            assert int(row[f"{key}_rank"]) == RANKS[i, d]
            for column, value in (("_true", truths[i, d]), ("_median", ordered[2]), ("_q05", low), ("_q95", high)):
                assert float(row[key + column]) == pytest.approx(value, rel=5e-6), (i, key, column)  # %.6g
