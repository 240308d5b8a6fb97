"""rhi power: the Monte Carlo power of a paired t test against its analytic value (noncentral t), and the command
end to end on a short protocol."""
import csv
import math

import numpy as np
import pytest
from scipy import stats

from rhi.master.studies import power

EFFECT, SD, STUDIES = 0.5, 1.0, 2000  # standardised difference 0.5: analytic powers 0.14, 0.29, 0.56 at n = 5, 10, 20
MC_BAND = 3.0  # standard errors: a correct estimator falls outside with probability 0.3 % (seeded: a fixed outcome)


def analytic_power(effect: float, n: int, alpha: float) -> float:
    """The two-sided paired t test's power on normal differences of standardised mean ``effect``: T is noncentral t
    with n - 1 degrees of freedom and noncentrality effect sqrt(n) (e.g. Cohen 1988, ch. 2)."""
    critical = stats.t.ppf(1 - alpha / 2, n - 1)
    shifted = stats.nct(n - 1, effect * math.sqrt(n))
    return float(shifted.sf(critical) + shifted.cdf(-critical))


def normal_study(study: int, n: int):
    """A study whose drifts are normal by construction: each participant's baseline, plus a difference
    N(EFFECT * SD, SD) under the first side."""
    rng = np.random.default_rng([20240607, study])
    baseline = rng.normal(0.0, 2.0, n)
    return baseline + rng.normal(EFFECT * SD, SD, n), baseline


def test_the_simulated_power_is_the_noncentral_t_power_within_its_monte_carlo_error():
    curve = power.power(normal_study, (5, 10, 20), STUDIES, alpha=0.05)
    for point in curve:
        expected = analytic_power(EFFECT, point.n, 0.05)
        standard_error = math.sqrt(expected * (1 - expected) / STUDIES)
        assert abs(point.power - expected) < MC_BAND * standard_error, (point, expected)
        assert point.mc_error == pytest.approx(math.sqrt(point.power * (1 - point.power) / STUDIES), rel=1e-12)
    assert [p.n for p in curve] == [5, 10, 20] and curve[0].power < curve[1].power < curve[2].power
    # no effect: the test's size, alpha, within the same band
    def no_effect(study: int, n: int):
        baseline = normal_study(study, n)[1]
        return baseline + np.random.default_rng([7, study]).normal(0.0, SD, n), baseline

    null = power.power(no_effect, (10,), STUDIES)[0]
    assert abs(null.power - 0.05) < MC_BAND * math.sqrt(0.05 * 0.95 / STUDIES)


def test_bad_requests_are_refused():
    from rhi.master.cosim import ConfigError

    with pytest.raises(ConfigError, match="at least 2 participants"):
        power.power(normal_study, (1, 10), 10)
    from rhi.master import config as configuration
    with pytest.raises(ConfigError, match="'together' is not a stimulation"):
        power.parse_contrast("sync-together", configuration.load())
    with pytest.raises(ConfigError, match="two different stimulations"):
        power.parse_contrast("sync", configuration.load())


SHORT = '''[experiment]
steps = 150                # 3 s: past the first touch (2 s), where sync and async part
conditions = ["left"]
[decoder]
fast = false
[population]
"brain.gamma0" = {distribution = "logit-normal", logit_sd = 1.0, high = 0.5}
'''


def test_rhi_power_writes_the_curve_of_a_short_protocol(tmp_path):
    from tests.faults import rhi

    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "short.toml").write_text(SHORT)
    done = rhi(tmp_path, "power", "--config", "short.toml", "--n", "3,2", "--studies", "2", "--out", "out",
               timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    with open(tmp_path / "work" / "out" / "power.csv") as file:
        rows = list(csv.DictReader(file))
    assert [row["n_participants"] for row in rows] == ["2", "3"]
    for row in rows:
        p = float(row["power"])
        assert p in (0.0, 0.5, 1.0)  # 2 studies
        assert float(row["power_mc_error"]) == pytest.approx(math.sqrt(p * (1 - p) / 2), rel=1e-5)
        assert float(row["sd_difference_drift_cm"]) > 0  # the participants differ (their gamma0)
    assert sorted(path.name for path in (tmp_path / "work" / "out").iterdir() if not path.name.startswith(".")) == \
        ["power.csv", "power.png", "run.json"]
