"""A fit of group data: a cell's mean and between-participant sd read from the data file, a population's median and
spread as fitted parameters, each simulated draw a study of fit.trials_per_cell participants whose cell means and
sds are the statistics. Checked without running a trial: the sweep's trials carry each study's participants, and
the statistics are the hand mean and sd of records made up for them."""
import statistics as python

import numpy as np
import pytest

from rhi.master.cosim import ConfigError
from rhi.master.fit.data import read_data

GROUP = """# a group: each cell's mean and between-participant sd
participant,condition,stimulation,drift_cm,drift_cm_sd
group,left,sync,-2.0,1.5
group,left,async,-0.1,0.4
"""
FIT = """[experiment]
steps = 5
[population]
"brain.gamma0" = {{distribution = "logit-normal", logit_sd = 1.0, high = 0.5}}
[fit]
simulations = 20
calibration = 0
trials_per_cell = {participants}
participants_per_batch = 2
[fit.parameters."population.brain.gamma0.median"]
prior = "log-uniform"
low = 0.005
high = 0.2
[fit.parameters."population.brain.gamma0.logit_sd"]
prior = "uniform"
low = 0.1
high = 2.0
"""


def write(path, text):
    path.write_text(text)
    return path


def test_a_groups_mean_and_sd_are_its_statistics(tmp_path):
    data = read_data(write(tmp_path / "g.csv", GROUP))
    assert data.measures == ["drift_cm", "drift_cm_sd"]
    assert data.observed.tolist() == [[-0.1, 0.4, -2.0, 1.5]]  # cells sorted: async, sync
    for text, message in ((GROUP.replace("drift_cm,drift_cm_sd", "force_n,drift_cm_sd"), "drift_cm_sd without its "
                           "measure drift_cm"), (GROUP.replace("-2.0,1.5", "-2.0,-1.5"), "is an sd: it must be >= 0")):
        with pytest.raises(ConfigError, match=message):
            read_data(write(tmp_path / "bad.csv", text))


def test_a_populations_median_and_spread_are_fitted_as_studies_of_n_participants(tmp_path):
    from rhi.master.fit.plan import read_plan
    from rhi.master.fit.simulate import participants_sweep, statistics

    data = read_data(write(tmp_path / "g.csv", GROUP))
    plan = read_plan(str(write(tmp_path / "fit.toml", FIT.format(participants=4))), data)
    assert [p.key for p in plan.parameters] == ["population.brain.gamma0.median", "population.brain.gamma0.logit_sd"]
    assert plan.measures == ["drift_cm", "drift_cm_sd"]
    theta = np.log([[0.01], [0.1]])  # the median's log-uniform prior: the inference space is its log
    theta = np.hstack([theta, [[0.0], [1.5]]])
    sweep = participants_sweep(plan, theta, "test")
    assert [len([t for t in sweep.trials if t.point == p and t.stimulation == "sync"]) for p in (0, 1)] == [4, 4]
    from rhi.master.config import population

    for point in (0, 1):  # each study's trials are its population's participants, the same one in both cells
        config = sweep.configs[point]
        assert config["population"]["brain.gamma0"]["median"] == pytest.approx(float(np.exp(theta[point, 0])))
        drawn = population.cohort(config, range(4))["brain.gamma0"]
        trials = [t for t in sweep.trials if t.point == point]
        own = {(t.stimulation, t.index): t for t in plan_trials(sweep, point)}
        for trial in trials:
            assert dict(own[(trial.stimulation, trial.index)].overrides)["brain.gamma0"] == drawn[trial.index]
    clones = population.cohort(sweep.configs[0], range(4))["brain.gamma0"]  # a spread of 0: every one the median
    assert np.all(clones == sweep.configs[0]["population"]["brain.gamma0"]["median"])
    assert len(set(population.cohort(sweep.configs[1], range(4))["brain.gamma0"])) == 4
    outcomes = {t.id: {"status": "ok", "outcome": {"drift_cm": float(n) ** 2 * (-1 if t.stimulation == "sync" else 1),
                                                   "force_n": 0.0}}
                for n, t in enumerate(sweep.trials)}
    x = statistics(sweep, outcomes, data, plan.measures)
    for point in (0, 1):
        for cell, stimulation in enumerate(("async", "sync")):
            values = [outcomes[t.id]["outcome"]["drift_cm"] for t in sweep.trials
                      if t.point == point and t.stimulation == stimulation]
            assert x[point, 2 * cell] == pytest.approx(python.mean(values), rel=1e-12)
            assert x[point, 2 * cell + 1] == pytest.approx(python.stdev(values), rel=1e-12)
    failed = {**outcomes, sweep.trials[0].id: {"status": "failed"}}
    assert np.isnan(statistics(sweep, failed, data, plan.measures)[sweep.trials[0].point]).sum() == 2  # its cell


def plan_trials(sweep, point):
    """The protocol trials of sweep point ``point``, as its runner makes them (rhi.master.config.protocol.plan)."""
    from rhi.master.config.protocol import plan

    return plan(sweep.configs[point])


def test_a_population_field_the_file_does_not_define_is_refused(tmp_path):
    from rhi.master.fit.plan import read_plan

    data = read_data(write(tmp_path / "g.csv", GROUP))
    for old, new, message in (("population.brain.gamma0.logit_sd", "population.brain.gamma1.logit_sd",
                               "has no entry 'brain.gamma1'"),
                              ("population.brain.gamma0.logit_sd", "population.brain.gamma0.sd",
                               "a logit-normal entry has no field 'sd'"),
                              ("low = 0.1\nhigh = 2.0", "low = -1.0\nhigh = 2.0", "logit_sd = -1.0 is a spread")):
        text = FIT.format(participants=4).replace(old, new)
        with pytest.raises(ConfigError, match=message):
            read_plan(str(write(tmp_path / "bad.toml", text)), data)


def test_a_batch_of_several_studies_gives_each_trial_its_participants_draws(tmp_path, monkeypatch):
    """The trials a sweep worker builds for a lockstep batch of several points (rhi.master.sweeps.runner.run_chunk, each
    point's configured values of every batchable key passed per trial) carry each participant's draw, not the
    point's configured median."""
    from rhi.master.config import population
    from rhi.master.fit.plan import read_plan
    from rhi.master.fit.simulate import participants_sweep
    from rhi.master.sweeps import runner
    from rhi.master.tasks.illusion import runner as illusion

    built = []
    monkeypatch.setattr(illusion, "batch_outcomes", lambda config, kind, protocol: built.extend(protocol) or
                        [{"status": "ok", "outcome": {}}] * len(protocol))
    plan = read_plan(str(write(tmp_path / "fit.toml", FIT.format(participants=3))), read_data(write(tmp_path / "g.csv",
                                                                                                     GROUP)))
    sweep = participants_sweep(plan, np.array([[np.log(0.02), 1.0], [np.log(0.05), 1.5]]), "test")
    chunk = [sweep.trials[p] for p in sweep.chunks[0]]
    assert {t.point for t in chunk} == {0, 1}
    runner.run_chunk(sweep.configs[0], chunk, [sweep.configs[t.point] for t in chunk])
    for spec, trial in zip(chunk, built):
        drawn = population.cohort(sweep.configs[spec.point], [spec.index])["brain.gamma0"][0]
        assert dict(trial.overrides)["brain.gamma0"] == drawn != sweep.configs[spec.point]["brain"]["gamma0"]


PROBES = """participant,condition,stimulation,drift_cm,drift_at_2s_cm,drift_at_2s_cm_sd,drift_cm_sd
group,left,sync,-2.0,-0.5,0.3,1.5
group,left,async,-0.1,-0.5,0.3,0.4
"""


def test_the_drift_read_within_the_trial_is_a_measure_whose_time_the_fit_reads(tmp_path):
    """A probe column (drift_at_2s_cm, its _sd) is a measure: ordered after drift_cm, its spread after drift_cm_sd; the
    fit's trials read the drift then (experiment.probe_times); a study's statistics are the hand mean and sd of the
    probe's values in made-up records."""
    from rhi.master.fit.plan import read_plan
    from rhi.master.fit.simulate import participants_sweep, statistics

    data = read_data(write(tmp_path / "p.csv", PROBES))
    assert data.measures == ["drift_cm", "drift_at_2s_cm", "drift_cm_sd", "drift_at_2s_cm_sd"]
    assert data.probe_times() == [2.0]
    assert data.observed.tolist() == [[-0.1, -0.5, 0.4, 0.3, -2.0, -0.5, 1.5, 0.3]]
    plan = read_plan(str(write(tmp_path / "fit.toml", FIT.format(participants=3).replace("steps = 5", "steps = 150"))),
                     data)
    assert plan.base["experiment"]["probe_times"] == [2.0] and plan.measures == data.measures
    sweep = participants_sweep(plan, np.array([[np.log(0.05), 1.0]]), "test")
    outcomes = {t.id: {"status": "ok", "outcome": {"drift_cm": -float(n), "drift_at_2s_cm": float(n) ** 2}}
                for n, t in enumerate(sweep.trials)}
    x = statistics(sweep, outcomes, data, plan.measures)
    for cell, stimulation in enumerate(("async", "sync")):
        probe = [outcomes[t.id]["outcome"]["drift_at_2s_cm"] for t in sweep.trials if t.stimulation == stimulation]
        assert x[0, 4 * cell + 1] == pytest.approx(python.mean(probe), rel=1e-12)
        assert x[0, 4 * cell + 3] == pytest.approx(python.stdev(probe), rel=1e-12)
    for old, new, message in (("drift_at_2s_cm,", "drift_at_2.0s_cm,", "write the probe's time as 'drift_at_2s_cm'"),
                              ("drift_at_2s_cm,drift_at_2s_cm_sd", "drift_at_3s_cm,drift_at_2s_cm_sd",
                               "drift_at_2s_cm_sd without its measure"),
                              ("drift_at_2s_cm,", "drift_at_2s_m,", "unknown column 'drift_at_2s_m'")):
        with pytest.raises(ConfigError, match=message):
            read_data(write(tmp_path / "bad.csv", PROBES.replace(old, new)))
    with pytest.raises(ConfigError, match="beyond the trial"):  # 5 steps of 0.02 s: the trial ends at 0.1 s
        read_plan(str(write(tmp_path / "short.toml", FIT.format(participants=3))), data)


ONSET = """participant,offset_m,delay_s,time_s,ownership_onset_s,ownership_onset_s_q90
group,-0.15,0,2,1.0,1.8
"""


def test_an_onsets_mean_and_percentile_are_a_studys_statistics_with_the_never_owned_beyond_the_trial(tmp_path):
    """ownership_onset_s and its percentile column: the mean over the participants who owned the hand, the 90th
    percentile (numpy's linear, type 7) over all, one who never did counted at the trial's end (2 s here); checked
    against the hand computation of made-up records. A model that does not record the measure is refused."""
    from rhi.master.fit.plan import read_plan
    from rhi.master.fit.simulate import participants_sweep, statistics

    data = read_data(write(tmp_path / "o.csv", ONSET))
    assert data.measures == ["ownership_onset_s", "ownership_onset_s_q90"]
    assert data.observed.tolist() == [[1.0, 1.8]]
    fit = FIT.format(participants=5).replace("steps = 5", "steps = 100").replace("[fit]\n", '[fit]\nmodel = "ownership"\n')
    plan = read_plan(str(write(tmp_path / "fit.toml", fit)), data)
    sweep = participants_sweep(plan, np.array([[np.log(0.05), 1.0]]), "test")
    onsets = [0.4, float("nan"), 1.2, 0.8, float("nan")]  # two never owned within the 2-s trial
    outcomes = {t.id: {"status": "ok", "outcome": {"ownership_onset_s": onsets[t.index]}} for t in sweep.trials}
    x = statistics(sweep, outcomes, data, plan.measures)
    # by hand: mean of 0.4, 1.2, 0.8 = 0.8; sorted with the never owned at 2.0: 0.4 0.8 1.2 2.0 2.0, the 90th
    # percentile at position 0.9 x 4 = 3.6 between 2.0 and 2.0: 2.0
    assert x[0].tolist() == pytest.approx([0.8, 2.0], rel=1e-12)
    onsets = [0.4, 0.6, 1.2, 0.8, float("nan")]  # one never owned: position 3.6 between 1.2 and 2.0
    outcomes = {t.id: {"status": "ok", "outcome": {"ownership_onset_s": onsets[t.index]}} for t in sweep.trials}
    x = statistics(sweep, outcomes, data, plan.measures)
    assert x[0].tolist() == pytest.approx([0.75, 1.2 + 0.6 * 0.8], rel=1e-12)
    failed = {**outcomes, sweep.trials[0].id: {"status": "failed"}}
    assert np.isnan(statistics(sweep, failed, data, plan.measures)).all()  # a failed trial is no participant's onset
    with pytest.raises(ConfigError, match="model 'paper' does not record it"):
        read_plan(str(write(tmp_path / "paper.toml", fit.replace('model = "ownership"', 'model = "paper"'))), data)
    with pytest.raises(ConfigError, match="without its measure ownership_onset_s"):
        read_data(write(tmp_path / "bad.csv", ONSET.replace("ownership_onset_s,", "drift_cm,")))
