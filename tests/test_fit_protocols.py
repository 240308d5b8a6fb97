"""A fit of several studies' protocols at once (the data's ``protocol`` column) and of a within-participant contrast
(its ``baseline`` column): each protocol's cells simulated under its own file, a contrast taken participant by
participant. Checked against the protocol files' own values and against hand statistics of records made up for the
sweep's trials; one tiny real run checks that each protocol's trials run its own trial length."""
import statistics as python

import numpy as np
import pytest

from rhi.master.cosim import ConfigError
from rhi.master.fit.data import read_data

DATA = """participant,protocol,condition,stimulation,baseline,time_s,drift_cm,drift_cm_sd
group,a.toml,near,sync,,0.1,-2.0,1.5
group,a.toml,near,async,,0.1,-0.1,0.4
group,b.toml,far,sync,async,1.0,-1.6,3.0
"""
PROTOCOL_A = """[conditions]
near = -0.15
[experiment]
trials = 3
"""
PROTOCOL_B = """[conditions]
far = -0.225
[stimulus]
period = 0.2
"""
FIT = """[population]
"brain.gamma0" = {distribution = "logit-normal", logit_sd = 1.0, high = 0.5}
[fit]
simulations = 20
calibration = 0
trials_per_cell = 2
participants_per_batch = 2
[fit.parameters."population.brain.gamma0.median"]
prior = "log-uniform"
low = 0.005
high = 0.2
"""


def files(folder, data=DATA, a=PROTOCOL_A, b=PROTOCOL_B, fit=FIT):
    for name, text in (("a.toml", a), ("b.toml", b), ("fit.toml", fit), ("data.csv", data)):
        (folder / name).write_text(text)
    return str(folder / "data.csv"), str(folder / "fit.toml")


def test_rows_of_several_protocols_are_one_data_set_protocol_by_protocol(tmp_path):
    data = read_data(files(tmp_path)[0])
    assert [part.protocol for part in data.parts] == ["a.toml", "b.toml"]
    assert data.cells == [("a.toml:near", "async"), ("a.toml:near", "sync"), ("b.toml:far", "sync-async")]
    assert data.observed.tolist() == [[-0.1, 0.4, -2.0, 1.5, -1.6, 3.0]]  # each part's cells sorted, cell-major
    assert data.parts[1].contrasts == {"sync-async": ("sync", "async")} and data.parts[0].contrasts == {}
    assert [part.time_s for part in data.parts] == [0.1, 1.0]


DELAYS = DATA.replace("stimulation,baseline", "delay_s,baseline").replace(",sync,", ",0.0,").replace(",async,", ",1.0,", 1)


@pytest.mark.parametrize("text, message", [
    (DATA.replace("b.toml,far", "c.toml,far"), "column protocol = 'c.toml': no such file"),
    (DATA.replace("group,b.toml", "other,b.toml"), "participant (group|other) has no rows of protocol"),
    (DATA.replace("sync,async,1.0", "sync,sync,1.0"), "is the row's own stimulation"),
    (DELAYS, "give the stimulation column"),  # a baseline names a stimulation: not beside delay_s
])
def test_a_bad_protocol_or_contrast_row_is_refused_in_one_line(tmp_path, text, message):
    with pytest.raises(ConfigError, match=message):
        read_data(files(tmp_path, data=text)[0])


def test_each_protocol_runs_its_own_design_and_group_size_in_batches_of_its_own(tmp_path):
    from rhi.master.fit.plan import read_plan
    from rhi.master.fit.simulate import participants_sweep

    data_path, fit_path = files(tmp_path)
    plan = read_plan(fit_path, read_data(data_path))
    a, b = plan.configs()
    step = a["experiment"]["step_size"]
    assert (a["experiment"]["steps"], b["experiment"]["steps"]) == (round(0.1 / step), round(1.0 / step))
    assert (a["experiment"]["trials"], b["experiment"]["trials"]) == (3, 2)  # a's file sets its n, b has the fit's
    assert (a["conditions"]["near"], b["conditions"]["far"], b["stimulus"]["period"]) == (-0.15, -0.225, 0.2)
    assert a["stimulus"]["period"] == plan.base["stimulus"]["period"]
    assert (a["experiment"]["stimulations"], b["experiment"]["stimulations"]) == (["async", "sync"], ["async", "sync"])
    theta = np.log([[0.01], [0.1], [0.05]])
    sweep = participants_sweep(plan, theta, "test")
    assert len(sweep.points) == 6  # protocol by protocol, a draw each
    for point in range(6):
        assert sweep.configs[point]["experiment"]["steps"] == (a if point < 3 else b)["experiment"]["steps"]
        assert sweep.points[point]["population.brain.gamma0.median"] == pytest.approx(np.exp(theta[point % 3, 0]))
    assert len({sweep.points[p]["experiment.seed"] for p in range(6)}) == 6  # another group of people each
    for chunk in sweep.chunks:  # two draws a batch, never two protocols in one
        assert len({sweep.trials[t].point // 3 for t in chunk}) == 1
    assert sorted(len({sweep.trials[t].point for t in chunk}) for chunk in sweep.chunks) == [1, 1, 2, 2]
    fitted = FIT.replace('population.brain.gamma0.median"]', 'brain.sync_sd"]').replace("0.005", "0.1").replace(
        "0.2\n", "0.5\n")
    with pytest.raises(ConfigError, match="protocol b.toml: sets brain.sync_sd, a fitted parameter"):
        read_plan(files(tmp_path, b=PROTOCOL_B + "[brain]\nsync_sd = 0.3\n", fit=fitted)[1], read_data(data_path))
    with pytest.raises(ConfigError, match=r"protocol a.toml: a protocol file gives a study's design; its \[fit\]"):
        read_plan(files(tmp_path, a=PROTOCOL_A + "[fit]\nseed = 1\n")[1], read_data(data_path))


def test_a_protocols_own_parameter_is_set_in_its_simulations_alone(tmp_path):
    """fit.parameters."b.toml:stimulus.period": a design value one study did not report, fitted as a nuisance
    parameter: named so in the outputs, set in b.toml's points (their configurations carry the drawn value) and in
    none of a.toml's (the fit file's value), its points still sharing lockstep batches; refused for a protocol the
    data do not have, for data without protocols, and where the protocol file sets the key itself."""
    from rhi.master.fit.plan import read_plan
    from rhi.master.fit.simulate import participants_sweep

    own = FIT + '[fit.parameters."b.toml:stimulus.period"]\nprior = "uniform"\nlow = 0.5\nhigh = 3.0\n'
    data_path, fit_path = files(tmp_path, b=PROTOCOL_B.replace("[stimulus]\nperiod = 0.2\n", ""), fit=own)
    plan = read_plan(fit_path, read_data(data_path))
    gamma0, period = plan.parameters
    assert (period.key, period.protocol, period.config_key) == ("b.toml:stimulus.period", "b.toml", "stimulus.period")
    assert (gamma0.protocol, gamma0.config_key) == ("", gamma0.key)
    theta = np.array([[np.log(0.01), 0.75], [np.log(0.1), 2.5], [np.log(0.05), 1.25]])
    sweep = participants_sweep(plan, theta, "test")
    for point in range(6):
        drawn = sweep.configs[point]["stimulus"]["period"]
        if point < 3:
            assert "stimulus.period" not in sweep.points[point] and drawn == plan.base["stimulus"]["period"]
        else:
            assert sweep.points[point]["stimulus.period"] == drawn == theta[point - 3, 1]
    assert sorted(len({sweep.trials[t].point for t in chunk}) for chunk in sweep.chunks) == [1, 1, 2, 2]
    refused = {own.replace('"b.toml:', '"c.toml:'): "'c.toml' is not a protocol of the data file",
               own: "protocol b.toml: sets stimulus.period, a fitted parameter"}
    for text, message in refused.items():
        with pytest.raises(ConfigError, match=message):
            read_plan(files(tmp_path, fit=text)[1], read_data(data_path))
    single = tmp_path / "single.csv"
    single.write_text("participant,condition,stimulation,drift_cm,drift_cm_sd\ngroup,left,sync,-2.0,1.5\n")
    with pytest.raises(ConfigError, match="'b.toml' is not a protocol of the data file .its protocols: none"):
        read_plan(files(tmp_path, fit=own)[1], read_data(single))


def test_each_protocols_statistics_and_a_contrast_are_the_hand_statistics_of_its_participants(tmp_path):
    from rhi.master.fit.plan import read_plan
    from rhi.master.fit.simulate import participants_sweep, statistics

    data_path, fit_path = files(tmp_path)
    data = read_data(data_path)
    plan = read_plan(fit_path, data)
    sweep = participants_sweep(plan, np.log([[0.01], [0.1]]), "test")

    def drift(t):  # made-up outcomes: every trial its own value
        return {"sync": -1.0, "async": 0.5}[t.stimulation] * (t.point + 1) * (t.index + 1) ** 2

    records = {t.id: {"status": "ok", "outcome": {"drift_cm": drift(t), "force_n": 0.0}} for t in sweep.trials}
    x = statistics(sweep, records, data, plan.measures)
    assert x.shape == (2, 6)
    for draw in (0, 1):
        sign = {"sync": -1.0, "async": 0.5}
        near = {s: [sign[s] * (draw + 1) * (k + 1) ** 2 for k in range(3)] for s in sign}
        far = [(-1.0 - 0.5) * (draw + 3) * (k + 1) ** 2 for k in range(2)]  # sync minus async, participant by participant
        expected = [python.mean(near["async"]), python.stdev(near["async"]), python.mean(near["sync"]),
                    python.stdev(near["sync"]), python.mean(far), python.stdev(far)]
        assert x[draw] == pytest.approx(expected, rel=1e-12)  # sums of a few exact binary fractions: rounding only
    records[next(t.id for t in sweep.trials if t.point == 3 and t.stimulation == "async")]["status"] = "failed"
    assert np.isnan(statistics(sweep, records, data, plan.measures)[1, 4:]).all()  # a failed baseline: no contrast


def test_a_real_protocols_studies_give_the_bits_of_a_sweep_of_them_alone(tmp_path):
    """The simulator, not made-up records: a protocol's studies, run beside another protocol's, give the bits of a
    sweep of those studies alone (a lockstep batch's numbers depend on its members: the same members, the same
    bits); the contrast is the difference of their trials, participant by participant."""
    from rhi.master.fit.plan import read_plan
    from rhi.master.fit.simulate import participants_sweep, statistics
    from rhi.master.sweeps import plan as sweeps
    from rhi.master.sweeps.runner import run_in_memory

    data_path, fit_path = files(tmp_path)
    data = read_data(data_path)
    plan = read_plan(fit_path, data)
    sweep = participants_sweep(plan, np.log([[0.01], [0.1]]), "test")
    records = run_in_memory(sweep)
    x = statistics(sweep, records, data, plan.measures)
    for points in ((0, 1), (2, 3)):
        alone = sweeps.build(plan.base, [sweep.points[p] for p in points], points_per_batch=2)
        own = run_in_memory(alone)
        by_cell = {(points[t.point], t.condition, t.stimulation, t.index): t.id for t in alone.trials}
        for trial in (t for t in sweep.trials if t.point in points):
            np.testing.assert_equal(records[trial.id]["outcome"],  # every value's bits, NaN equal to NaN
                                    own[by_cell[trial.point, trial.condition, trial.stimulation, trial.index]]["outcome"])
    for draw in (0, 1):
        drift = {(t.stimulation, t.index): records[t.id]["outcome"]["drift_cm"] for t in sweep.trials
                 if t.point == 2 + draw}
        far = [drift["sync", k] - drift["async", k] for k in range(2)]
        assert x[draw, 4:].tolist() == [python.mean(far), python.stdev(far)]
        assert abs(x[draw, 4]) > 1e-6  # strokes within the second: the two stimulations part


def test_each_participants_own_measurement_error_enters_the_groups_statistics(tmp_path):
    """fit.participant_noise: every simulated participant's value gets an error of its own before the group's mean
    and sd (and before a contrast's difference: two judgements, two errors), drawn as documented."""
    from rhi.master.fit.plan import read_plan
    from rhi.master.fit.simulate import participants_sweep, simulated_statistics

    data_path, fit_path = files(tmp_path, fit=FIT.replace("[fit]\n", "[fit]\nparticipant_noise = {drift_cm = 1.5}\n"))
    data = read_data(data_path)
    plan = read_plan(fit_path, data)
    assert plan.participant_noise == {"drift_cm": 1.5}
    sweep = participants_sweep(plan, np.log([[0.01], [0.1]]), "test")
    records = {t.id: {"status": "ok", "outcome": {"drift_cm": float(t.index), "force_n": 0.0}} for t in sweep.trials}
    x = simulated_statistics(plan, sweep, records, data, "prior")
    error = dict(zip((t.id for t in sweep.trials), 1.5 * np.random.default_rng(
        [plan.settings["seed"], 2, sum(map(ord, "prior")), sum(map(ord, "drift_cm"))]).standard_normal(len(sweep.trials))))
    value = {(t.point, t.stimulation, t.index): t.index + error[t.id] for t in sweep.trials}
    near = [value[1, "sync", k] for k in range(3)]  # draw 1 of protocol a: point 1
    far = [value[3, "sync", k] - value[3, "async", k] for k in range(2)]  # draw 1 of protocol b: point 3
    assert x[1, 2:4].tolist() == pytest.approx([python.mean(near), python.stdev(near)], rel=1e-12)
    assert x[1, 4:].tolist() == pytest.approx([python.mean(far), python.stdev(far)], rel=1e-12)
    for bad, message in (("drift_cm_sd = 1.0", "unknown fit key fit.participant_noise.drift_cm_sd"),
                         ("drift_cm = -1.0", "must be a number >= 0")):
        text = FIT.replace("[fit]\n", f"[fit]\nparticipant_noise = {{{bad}}}\n")
        with pytest.raises(ConfigError, match=message):
            read_plan(files(tmp_path, fit=text)[1], data)


def test_a_fit_of_two_protocols_runs_and_its_simulations_serve_a_fit_with_other_statistics(tmp_path, capsys):
    """rhi fit end to end on two protocols (a tiny paper-model fit); the same draws fitted again with each
    participant's measurement error, from a copy of its simulations/: no trial runs again. A folder holding another
    fit's simulations is refused in one line."""
    import json
    import shutil

    from rhi.master.commands.cli import main

    tiny = FIT.replace("[fit]\n", "[fit]\npredictive_draws = 0\n").replace("simulations = 20", "simulations = 10") + (
        "[fit.estimator]\nhidden_features = 8\ntransforms = 1\nmax_epochs = 5\n")  # the folders, not the estimator
    data_path, fit_path = files(tmp_path, fit=tiny)
    first = tmp_path / "first"
    assert main(["fit", "--data", data_path, "--config", fit_path, "--out", str(first)]) == 0
    run = json.loads((first / "run.json").read_text())
    assert run["statistics"][-2:] == ["drift_cm[b.toml:far/sync-async]", "drift_cm_sd[b.toml:far/sync-async]"]
    assert run["protocols"]["b.toml"]["experiment.steps"] == 50 and run["simulations"]["steps_per_trial"] == [5, 50]
    assert run["simulations"]["trials"] == 10 * (2 * 3 + 2 * 2)  # a: 2 cells x its 3; b: sync and async x 2
    second = tmp_path / "second"
    second.mkdir()
    shutil.copytree(first / "simulations", second / "simulations")
    noisy = tiny.replace("[fit]\n", "[fit]\nparticipant_noise = {drift_cm = 1.0}\n")
    (tmp_path / "fit.toml").write_text(noisy)
    assert main(["fit", "--data", data_path, "--config", fit_path, "--out", str(second)]) == 0
    again = json.loads((second / "run.json").read_text())
    assert again["simulations"]["trials_run_now"] == 0 and again["participant_noise"] == {"drift_cm": 1.0}
    assert again["seeds"] == run["seeds"]
    other = tmp_path / "other"
    other.mkdir()
    shutil.copytree(first / "simulations", other / "simulations")
    (tmp_path / "b.toml").write_text(PROTOCOL_B.replace("period = 0.2", "period = 0.25"))
    capsys.readouterr()
    assert main(["fit", "--data", data_path, "--config", fit_path, "--out", str(other)]) == 2
    assert "is not empty and holds no fit" in capsys.readouterr().err


def test_a_groups_correlation_of_two_measures_is_pearsons_r_over_its_participants(tmp_path):
    """r_drift_cm_vs_force_n: Pearson's r over each cell's participants (python's statistics.correlation by hand),
    in a contrast's cell of the participants' differences; refused without its measures or outside [-1, 1]."""
    from rhi.master.fit.plan import read_plan
    from rhi.master.fit.simulate import participants_sweep, statistics

    text = DATA.replace("drift_cm,drift_cm_sd", "drift_cm,force_n,r_drift_cm_vs_force_n").replace(
        "-2.0,1.5", "-2.0,0.1,0.9").replace("-0.1,0.4", "-0.1,0.0,0.5").replace("-1.6,3.0", "-1.6,0.0,0.2")
    data = read_data(files(tmp_path, data=text)[0])
    assert data.measures == ["drift_cm", "force_n", "r_drift_cm_vs_force_n"]
    plan = read_plan(str(tmp_path / "fit.toml"), data)
    sweep = participants_sweep(plan, np.log([[0.01], [0.1]]), "test")
    sign = {"sync": -1.0, "async": 0.5}

    def outcome(t):  # two measures that do not move together exactly
        return {"drift_cm": sign[t.stimulation] * (t.index + 1) ** 2 * (t.point + 1),
                "force_n": sign[t.stimulation] * (t.index + 1) + 0.1 * t.point}

    records = {t.id: {"status": "ok", "outcome": outcome(t)} for t in sweep.trials}
    x = statistics(sweep, records, data, plan.measures).reshape(2, 3, 3)
    for draw in (0, 1):
        by = {(t.stimulation, t.index): outcome(t) for t in sweep.trials if t.point == draw}
        drift, force = ([by["sync", k][m] for k in range(3)] for m in ("drift_cm", "force_n"))
        assert x[draw, 1, 2] == pytest.approx(python.correlation(drift, force), rel=1e-12)
        by = {(t.stimulation, t.index): outcome(t) for t in sweep.trials if t.point == 2 + draw}
        drift, force = ([by["sync", k][m] - by["async", k][m] for k in range(2)] for m in ("drift_cm", "force_n"))
        assert np.isnan(x[draw, 2, 2])  # two participants: no correlation (three at least)
        assert x[draw, 2, :2].tolist() == pytest.approx([python.mean(drift), python.mean(force)], rel=1e-12)
    for bad, message in ((text.replace("drift_cm,force_n,r_", "drift_cm,force_x,r_"), "unknown column 'force_x'"),
                         (text.replace(",force_n,r_drift_cm", ",drift_cm_sd,r_drift_cm"), "without its measures"),
                         (text.replace("-2.0,0.1,0.9", "-2.0,0.1,1.5"), "is a correlation: it must lie in")):
        with pytest.raises(ConfigError, match=message):
            read_data(files(tmp_path, data=bad)[0])


def test_the_model_at_a_point_is_the_simulation_of_that_point_repeated(tmp_path):
    """rhi.fit.memory.at_point: count studies at one point are simulate's rows for that point's draw, each with its
    own seed (so the studies differ), the point given in its parameters' own units."""
    from rhi.master.fit import memory
    from rhi.master.fit.plan import read_plan

    data_path, fit_path = files(tmp_path)
    data = read_data(data_path)
    plan = read_plan(fit_path, data)
    x = memory.at_point(plan, data, {"population.brain.gamma0.median": 0.05}, count=2, stream="t")
    np.testing.assert_array_equal(x, memory.simulate(plan, data, np.log([[0.05], [0.05]]), "t"))
    assert not np.array_equal(x[0], x[1])
    with pytest.raises(KeyError, match="population.brain.gamma0.median"):
        memory.at_point(plan, data, {}, count=1)
