"""The fit's SBC beside sbi's own (sbi.diagnostics.sbc): the ranks are sbi's rank count on the same samples; the
KS test of the ranks is kept by hand because sbi's, on discrete ranks, fails calibrated posteriors far more often
at few samples (docs/fit.md, "The rank tests by hand")."""
import numpy as np
import pytest
import torch

from rhi.master.fit.calibration import sbc_ranks, uniformity

sbc = pytest.importorskip("sbi.diagnostics.sbc")


def test_the_ranks_equal_sbi_s_marginal_rank_count_on_the_same_samples():
    generator = np.random.default_rng(7)
    participants, samples, parameters = 40, 19, 3
    truths = generator.normal(size=(participants, parameters))
    drawn = generator.normal(size=(participants, samples, parameters)) + 0.3  # a biased posterior: skewed ranks
    theirs = sbc._run_sbc(torch.as_tensor(truths), torch.zeros(participants, 1),  # x unused by the marginals
                          torch.as_tensor(drawn).transpose(0, 1), "marginals", show_progress_bar=False)
    assert np.array_equal(sbc_ranks(drawn, truths), theirs.numpy().astype(int))


def test_sbi_s_ks_test_reads_discrete_ranks_as_continuous_on_0_to_l():
    """Why the KS test stays by hand: sbi tests the integer ranks against U(0, L); the fit tests the mid-ranks
    (rank + 1/2) / (L + 1) against U(0, 1). Ranks spread evenly over {0, ..., L} (every value equally often, the
    most uniform a calibrated posterior's ranks can be) pass the fit's test and fail sbi's at L = 9."""
    L, each = 9, 10
    ranks = np.repeat(np.arange(L + 1), each)[:, None]                 # 100 participants
    ours = uniformity(ranks, L)["ks_p"][0]
    theirs = float(sbc.check_uniformity_frequentist(torch.as_tensor(ranks, dtype=torch.float32), L)[0])
    # The KS distances by hand: the mid-ranks' ECDF is off U(0, 1)'s CDF by at most 1/(2(L + 1)) = 0.05; the ranks'
    # ECDF jumps to 1/(L + 1) = 0.1 at 0, where U(0, L)'s CDF is 0. Their p-values: the exact two-sided KS law of
    # 100 draws (scipy.stats.kstwo), to float64 rounding for ours and float32's (sbi's tensor) for sbi's.
    from scipy.stats import kstwo

    assert ours == pytest.approx(kstwo.sf(0.05, 100), rel=1e-9)       # 0.953: uniform
    assert theirs == pytest.approx(kstwo.sf(0.1, 100), rel=1e-6)      # 0.253
