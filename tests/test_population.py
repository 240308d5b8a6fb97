"""The [population] table: its distributions against scipy.stats, the cohort reproduced from the seed, its refusals,
and a run with a fixed population giving the bytes of a run with none."""
import numpy as np
import pytest
from scipy import special, stats

from rhi.master import config as configuration
from rhi.master.config import population
from rhi.master.config.protocol import plan
from rhi.master.cosim import ConfigError

KS_ALPHA = 0.01  # each distribution's KS test rejects a correct sampler with probability 1 % (seeded: fixed outcome)
DRAWS = 10_000


def with_population(table: dict, **overrides) -> dict:
    """The shipped configuration with ``table`` as its [population] (validated as a user's file would be)."""
    config = configuration.merge(configuration.load(overrides=overrides or None), {"population": table})
    configuration.validate(config)
    return config


# (entry, the scipy.stats distribution it must follow, a map of the draws to that distribution's variable)
CASES = {
    "normal": ({"distribution": "normal", "median": 0.5, "sd": 0.1}, stats.norm(0.5, 0.1), None),
    "truncated normal": ({"distribution": "normal", "median": 0.5, "sd": 0.2, "low": 0.3, "high": 1.0},
                         stats.truncnorm((0.3 - 0.5) / 0.2, (1.0 - 0.5) / 0.2, loc=0.5, scale=0.2), None),
    "log-normal": ({"distribution": "log-normal", "median": 0.06, "log_sd": 0.4}, stats.lognorm(0.4, scale=0.06),
                   None),
    # scipy has no logit-normal: logit(x) is normal by definition (Aitchison & Shen 1980)
    "logit-normal": ({"distribution": "logit-normal", "median": 0.3, "logit_sd": 0.8},
                     stats.norm(special.logit(0.3), 0.8), special.logit),
    "uniform": ({"distribution": "uniform", "low": 0.2, "high": 0.7}, stats.uniform(0.2, 0.5), None),
}


@pytest.mark.parametrize("name", CASES)
def test_ten_thousand_draws_follow_the_configured_distribution(name):
    entry, reference, transform = CASES[name]
    # cohort() reads the master seed, the entries and a median's key; this key's own value stands unused beside them
    config = {"experiment": {"seed": 0}, "population": population.checked_table({"any.key": entry}),
              "any": {"key": 1.0}}
    draws = population.cohort(config, range(DRAWS))["any.key"]
    values = transform(draws) if transform else draws
    assert stats.kstest(values, reference.cdf).pvalue > KS_ALPHA


def test_the_cohort_is_reproduced_from_the_seed_by_an_independent_computation():
    """Each value is scipy's quantile function at the participant's own uniform variate: numpy's generator seeded
    with (sha256 of "seed/participant/index", 3, sha256 of the key), 53 bits offset by half."""
    import hashlib

    table = {"brain.gamma0": {"distribution": "logit-normal", "logit_sd": 1.0, "high": 0.5},
             "decoder.visual_variance": {"distribution": "log-normal", "log_sd": 0.3},
             "brain.proprioceptive_variance": {"distribution": "normal", "sd": 0.2, "low": 0.5, "high": 1.5}}
    config = with_population(table, **{"experiment.trials": 4, "experiment.seed": 7})
    drawn = population.cohort(config, range(4))

    def u(index, key):
        seed = int.from_bytes(hashlib.sha256(f"7/participant/{index}".encode()).digest()[:8], "little") >> 1
        code = int.from_bytes(hashlib.sha256(key.encode()).digest()[:4], "little")
        return (float(np.random.default_rng([seed, 3, code]).integers(0, 2**53)) + 0.5) / 2**53

    gamma0, variance = config["brain"]["gamma0"], config["decoder"]["visual_variance"]
    logit = stats.norm(special.logit(gamma0), 1.0)
    for index in range(4):
        # logit-normal truncated above at 0.5: the normal of logit x truncated at logit(0.5)
        expected = special.expit(logit.ppf(u(index, "brain.gamma0") * logit.cdf(special.logit(0.5))))
        assert drawn["brain.gamma0"][index] == pytest.approx(expected, rel=1e-12)  # two float64 paths: ulps apart
        expected = stats.lognorm(0.3, scale=variance).ppf(u(index, "decoder.visual_variance"))
        assert drawn["decoder.visual_variance"][index] == pytest.approx(expected, rel=1e-12)
        expected = stats.truncnorm(-2.5, 2.5, loc=1.0, scale=0.2).ppf(u(index, "brain.proprioceptive_variance"))
        assert drawn["brain.proprioceptive_variance"][index] == pytest.approx(expected, rel=1e-9)  # scipy's
        # truncnorm inverts its own CDF numerically: agreement to about 1e-10
    again = population.cohort(with_population(table, **{"experiment.trials": 4, "experiment.seed": 7}), range(4))
    assert all(np.array_equal(again[key], drawn[key]) for key in drawn)
    other = population.cohort(with_population(table, **{"experiment.trials": 4, "experiment.seed": 8}), range(4))
    assert not np.array_equal(other["brain.gamma0"], drawn["brain.gamma0"])


def test_a_participant_runs_every_cell_and_a_key_added_leaves_the_others_draws():
    one = {"brain.gamma0": {"distribution": "log-normal", "log_sd": 0.5, "high": 1.0}}
    config = with_population(one, **{"experiment.trials": 3})
    trials = plan(config)
    for trial in trials:  # the same person in every decoder, condition and stimulation: one value per index
        assert dict(trial.overrides)["brain.gamma0"] == population.cohort(config, [trial.index])["brain.gamma0"][0]
    assert len({dict(t.overrides)["brain.gamma0"] for t in trials}) == 3
    two = {**one, "decoder.visual_variance": {"distribution": "uniform", "low": 10.0, "high": 40.0}}
    wider = with_population(two, **{"experiment.trials": 3})
    assert np.array_equal(population.cohort(wider, range(3))["brain.gamma0"],
                          population.cohort(config, range(3))["brain.gamma0"])


def test_a_participant_is_drawn_once_however_often_the_protocol_is_planned():
    one = {"brain.gamma0": {"distribution": "log-normal", "log_sd": 0.5, "high": 1.0},
           "decoder.visual_variance": {"distribution": "log-normal", "log_sd": 0.3}}
    config = with_population(one, **{"experiment.trials": 3})
    population.drawn.cache_clear()
    first = plan(config)
    for _ in range(3):  # a lockstep batch plans its protocol three times as it is built
        assert plan(config) == first
    # 3 participants x 2 keys drawn, not again for each of the 6 cells x 2 decoders nor for each plan
    assert population.drawn.cache_info().misses == 3 * 2


@pytest.mark.parametrize("table, message", [
    ({"brain.gama0": {"distribution": "normal", "sd": 0.01}},
     r"population.brain.gama0 is not a parameter of the paper model .*did you mean brain.gamma0\?"),
    ({"experiment.trials": {"distribution": "normal", "sd": 1.0}}, "experiment.trials is not a parameter"),
    ({"brain.gamma0": {"distribution": "gamma", "sd": 0.01}}, "distribution = 'gamma' is not one of fixed, normal"),
    ({"brain.gamma0": {"distribution": "log-normal", "log_sd": -0.1}}, "log_sd = -0.1 is a spread: it must be >= 0"),
    ({"brain.gamma0": {"distribution": "log-normal", "log_sd": 0.1, "low": 0.02}},
     r"bounds \[0.02, inf\] exclude the median 0.01"),
    ({"brain.gamma0": {"distribution": "normal", "sd": 0.1, "high": 0.5}}, "gamma0's range"),
    ({"brain.gamma0": {"distribution": "uniform", "low": 0.1}}, "needs low and high"),
    ({"brain.gamma0": {"distribution": "normal"}}, "needs sd"),
    ({"brain.gamma0": {"distribution": "log-normal", "sd": 0.1}}, "takes median, log_sd, low, high, not 'sd'"),
    ({"brain.gamma0": {"distribution": "logit-normal", "logit_sd": 0.1, "median": 1.5}}, "outside a logit-normal"),
    ({"brain.gamma0": "normal"}, "must be a table"),
])
def test_nonsense_is_one_clear_config_error(table, message):
    with pytest.raises(ConfigError, match=message) as caught:
        with_population(table)
    assert "\n" not in str(caught.value)


def test_the_command_line_refuses_a_bad_population_in_one_line(tmp_path):
    from tests.faults import refused, rhi

    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "bad.toml").write_text('[population]\n"brain.gamma0" = {distribution = "normal", sd = -1.0}\n')
    refused(rhi(tmp_path, "experiment", "--config", "bad.toml", "--out", "out"), "sd = -1.0 is a spread")
    assert not (tmp_path / "work" / "out").exists()


def tiny_run(config: dict):
    """The protocol of ``config`` in one lockstep batch per decoder slot through an untrained tiny 16 px decoder:
    summary.csv's and trials.csv's text, and the per-step measures."""
    from rhi.components.body import kinematics
    from rhi.components.vision.component import Decoder, GenerativeModel
    from rhi.components.vision.networks import build
    from rhi.master import models
    from rhi.master.outputs import tables
    from rhi.master.tasks.illusion import wiring
    from rhi.master.tasks.illusion.measures import end_of_trial, measures

    trials = plan(config)
    decoder = Decoder(GenerativeModel(build("conv", "tiny", 16).decoder, kinematics.REST_POSE, (40.0, 50.0),
                                      {"kind": "conv"}), threads=1)
    result = wiring.run_batch(decoder, trials, config)
    per_step = measures(result, models.of(config))
    final = end_of_trial(result.times, per_step, ())
    summary = tables.csv_text(tables.summary_columns(), tables.summary(trials, final))
    return summary, tables.trials_csv(trials, result.times, per_step), per_step


TINY = {"experiment.resolution": 16, "experiment.steps": 12, "experiment.trials": 2, "experiment.decoders": ["conv"],
        "experiment.conditions": ["left"]}


def test_a_fixed_population_gives_the_bytes_of_none_and_a_spread_reaches_each_brain():
    import torch

    torch.manual_seed(0)  # the untrained decoder's weights: the same in every run below
    state = torch.random.get_rng_state()
    none = tiny_run(configuration.load(overrides=TINY))
    fixed = {"brain.gamma0": {"distribution": "fixed"},
             "decoder.visual_variance": {"distribution": "log-normal", "log_sd": 0.0}}
    torch.random.set_rng_state(state)
    same = tiny_run(with_population(fixed, **TINY))
    assert same[0] == none[0] and same[1] == none[1]
    spread = {"brain.gamma0": {"distribution": "logit-normal", "logit_sd": 1.0, "high": 0.5}}
    config = with_population(spread, **TINY)
    torch.random.set_rng_state(state)
    gamma = tiny_run(config)[2]["gamma"]
    drawn = population.cohort(config, range(2))["brain.gamma0"]
    # gamma starts at gamma0 (the brain's initial state, recorded at step 0), float32-rounded by the recording
    assert np.allclose(gamma[0], [drawn[t.index] for t in plan(config)], rtol=1e-6)
    assert drawn[0] != drawn[1]


def test_the_cohort_columns_are_the_statistics_of_each_cells_participants():
    """Truth: Python's statistics module (its inclusive quantiles are the linear, type 7, quantiles numpy's default
    computes) and a hand list of the cells."""
    import statistics as python
    from types import SimpleNamespace

    from rhi.master.outputs import cohort, tables

    trials = [SimpleNamespace(decoder="conv", condition="left", stimulation=stimulation, index=index)
              for stimulation in ("sync", "async") for index in range(7)]
    values = np.array([-3.0, -1.0, -2.5, -4.0, 0.5, -2.0, -1.5, 0.1, -0.2, 0.3, 0.0, -0.1, 0.2, 0.4])
    onset = np.array([5.0, 9.0, np.nan, 7.0, 12.0, 6.0, 30.0] + [np.nan] * 7)
    final = {key: values for key in cohort.MEASURES} | {"ownership_onset_s": onset}
    measures = cohort.measures_of(("ownership_onset_s",))
    present = tables.summary_columns()
    header = cohort.columns(measures, present)
    assert header[:4] == ["drift_cm_q10", "drift_cm_q50", "drift_cm_q90", "force_n_q10"]
    assert "gamma_final_sd" in header and "drift_cm_sd" not in header  # summary.csv has drift's sd already
    assert header[-5:] == [f"ownership_onset_s_{s}" for s in ("mean", "sd", "q10", "q50", "q90")]
    planned = [("conv", "left", "sync"), ("conv", "left", "async"), ("conv", "right", "sync")]
    rows = cohort.summary_cells(trials, final, planned, measures, present)
    for row, half in zip(rows, (values[:7], values[7:])):
        deciles = python.quantiles(half.tolist(), n=10, method="inclusive")
        got = dict(zip(header, row))
        assert [float(got[f"drift_cm_q{q}"]) for q in (10, 50, 90)] == pytest.approx(
            [deciles[0], deciles[4], deciles[8]], rel=1e-5)  # written with %.6g: 6 significant digits
        assert float(got["gamma_final_sd"]) == pytest.approx(python.stdev(half.tolist()), rel=1e-5)
    defined = [5.0, 9.0, 7.0, 12.0, 6.0, 30.0]  # the onsets reached; the never reached one is left out
    got = dict(zip(header, rows[0]))
    assert float(got["ownership_onset_s_mean"]) == pytest.approx(python.mean(defined), rel=1e-5)
    assert float(got["ownership_onset_s_q90"]) == pytest.approx(python.quantiles(defined, n=10, method="inclusive")[8],
                                                                rel=1e-5)
    assert dict(zip(header, rows[1]))["ownership_onset_s_mean"] == "nan"  # no participant reached it
    assert rows[2] == [""] * len(header)  # a planned cell whose trials all failed


def test_participants_csv_and_the_strip_figure_show_each_participant():
    from types import SimpleNamespace

    from matplotlib.figure import Figure

    from rhi.master.outputs import cohort

    text = cohort.participants_csv(range(2), [11, 12], {"brain.gamma0": np.array([0.0123456789, 0.02])})
    assert text == "participant,participant_seed,brain.gamma0\n0,11,0.0123457\n1,12,0.02\n"
    trials = [SimpleNamespace(decoder="conv", condition=condition, stimulation="sync", index=index)
              for condition in ("left", "right") for index in range(3)]
    drift = np.array([-1.0, -2.0, -4.0, 1.0, 2.0, 3.0])
    figure = cohort.strip_figure(trials, {"drift_cm": drift}, ["drift_cm"])
    assert isinstance(figure, Figure)
    lines = figure.axes[0].lines
    dots = [line for line in lines if line.get_gid() == "participants"]
    assert [list(line.get_ydata()) for line in dots] == [[-1.0, -2.0, -4.0], [1.0, 2.0, 3.0]]
    medians = [line.get_ydata()[0] for line in lines if line.get_gid() == "median"]
    assert medians == [-2.0, 2.0]


@pytest.mark.parametrize("model", ["paper", "causal", "ownership"])
def test_a_fixed_population_leaves_every_models_trials_and_parameters_as_they_were(model):
    """The same trials and the same value of every component parameter: the same run, for each built-in model."""
    from rhi.master.config.sources import batchable_keys, parameters

    base = configuration.load(model_name=model, overrides={"experiment.trials": 2})
    fixed = {key: {"distribution": "fixed"} for key in sorted(batchable_keys(base))}
    config = configuration.merge(base, {"population": fixed})
    configuration.validate(config)
    assert plan(config) == plan(base)
    given, expected = parameters(plan(config), config), parameters(plan(base), base)
    assert given.keys() == expected.keys()
    for path in expected:
        assert np.array_equal(np.asarray(given[path]), np.asarray(expected[path]), equal_nan=True), path  # NaN: padding


def test_a_models_own_key_varies_its_derived_parameter_per_participant():
    """ownership.peripersonal_boundary reaches the ownership brain as its peripersonal sd, derived per participant
    from the drawn boundary and the arm's reach."""
    from rhi.components.body.kinematics import FOREARM, UPPER_ARM
    from rhi.components.brain.ownership_inference import peripersonal_sd_from_boundary
    from rhi.master.config.sources import parameters

    base = configuration.load(model_name="ownership", overrides={"experiment.trials": 3})
    config = configuration.merge(base, {"population": {"ownership.peripersonal_boundary": {
        "distribution": "log-normal", "log_sd": 0.1}}})
    configuration.validate(config)
    trials = plan(config)
    drawn = population.cohort(config, range(3))["ownership.peripersonal_boundary"]
    expected = [peripersonal_sd_from_boundary(drawn[t.index], UPPER_ARM + FOREARM) for t in trials]
    assert np.allclose(parameters(trials, config)["brain.peripersonal_sd"], expected, rtol=1e-15, atol=0)
    assert len(set(drawn)) == 3


COHORT_RUN = '''[experiment]
steps = 20
trials = 3
decoders = ["conv"]
conditions = ["left"]
[decoder]
fast = false
[population]
"brain.gamma0" = {distribution = "logit-normal", logit_sd = 1.0, high = 0.5}
"decoder.visual_variance" = {distribution = "uniform", low = 10.0, high = 30.0}
'''


def test_rhi_experiment_with_a_population_writes_the_cohort(tmp_path):
    """The appended columns are the statistics of trials.csv's own final rows; participants.csv is the cohort."""
    import csv
    import statistics as python

    from tests.faults import rhi

    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "cohort.toml").write_text(COHORT_RUN)
    done = rhi(tmp_path, "experiment", "--config", "cohort.toml", "--out", "out", timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    out = tmp_path / "work" / "out"
    with open(out / "summary.csv") as file:
        header, *rows = list(csv.reader(file))
    from rhi.master.outputs import tables
    assert header[:len(tables.SUMMARY_COLUMNS)] == tables.SUMMARY_COLUMNS and "drift_cm_q90" in header
    with open(out / "trials.csv") as file:
        last = [row for row in csv.DictReader(file) if row["step"] == "20"]
    for row in rows:
        cell = dict(zip(header, row))
        drifts = [float(r["drift_cm"]) for r in last if r["stimulation"] == cell["stimulation"]]
        assert len(set(drifts)) == 3  # three different participants
        deciles = python.quantiles(drifts, n=10, method="inclusive")  # type 7, numpy's default
        for column, expected in (("drift_cm_q10", deciles[0]), ("drift_cm_q50", deciles[4]),
                                 ("drift_cm_q90", deciles[8])):
            assert float(cell[column]) == pytest.approx(expected, rel=1e-4, abs=1e-9)  # from 6-digit trial rows
    config = configuration.load(tmp_path / "work" / "cohort.toml")
    drawn = population.cohort(config, range(3))
    with open(out / "participants.csv") as file:
        listed = list(csv.DictReader(file))
    assert [row["participant"] for row in listed] == ["0", "1", "2"]
    for key, values in drawn.items():
        assert [float(row[key]) for row in listed] == pytest.approx(values.tolist(), rel=1e-5)  # %.6g
    assert (out / "figures" / "cohort.png").stat().st_size > 0


def test_a_sweep_varies_a_populations_spread_and_batches_its_points_together():
    """A point's population.KEY.FIELD merges into that entry; points differing only in their population share a
    lockstep batch, each trial carrying its own participant's draws."""
    from rhi.master.sweeps import plan as sweeps

    base = with_population({"brain.gamma0": {"distribution": "logit-normal", "logit_sd": 1.0, "high": 0.5}},
                           **{"experiment.trials": 2, "experiment.decoders": ["conv"],
                              "experiment.conditions": ["left"]})
    sweep = sweeps.build(base, [{"population.brain.gamma0.logit_sd": 0.0}, {"population.brain.gamma0.logit_sd": 2.0}],
                         points_per_batch=2)
    assert sweep.configs[1]["population"]["brain.gamma0"] == {"distribution": "logit-normal", "logit_sd": 2.0,
                                                               "high": 0.5}
    assert len(sweep.chunks) == 1  # one lockstep batch for both points
    wide = population.cohort(sweep.configs[1], range(2))["brain.gamma0"]
    narrow = population.cohort(sweep.configs[0], range(2))["brain.gamma0"]
    assert np.all(narrow == base["brain"]["gamma0"]) and len(set(wide)) == 2
    written = with_population({"brain.gamma0": {"distribution": "logit-normal", "logit_sd": 2.0, "high": 0.5}},
                              **{"experiment.trials": 2})  # the point's population, written out in a file
    assert np.array_equal(wide, population.cohort(written, range(2))["brain.gamma0"])
    with pytest.raises(ConfigError, match="logit_sd = -1.0 is a spread"):
        sweeps.build(base, [{"population.brain.gamma0.logit_sd": -1.0}])


def test_the_tasks_whose_trials_are_not_participants_refuse_a_population(tmp_path):
    from rhi.master.tasks import moving_hand
    from rhi.master.tasks.reach import task as reach

    path = tmp_path / "pop.toml"
    path.write_text('[population]\n"brain.gamma0" = {distribution = "log-normal", log_sd = 0.5, high = 1.0}\n')
    with pytest.raises(ConfigError, match="rhi reach runs no \\[population\\]"):
        reach.load(path)
    with_protocol = tmp_path / "moving.toml"
    with_protocol.write_text(moving_hand.shipped_file().read_text() + path.read_text())
    with pytest.raises(ConfigError, match="moving-hand runs no \\[population\\]"):
        moving_hand.load(with_protocol)
