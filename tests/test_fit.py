"""rhi fit: the calibration's arithmetic against hand and analytic truth, the data and fit files' refusals, a
lockstep batch of several configurations against each alone, and a tiny fit end to end, killed and resumed.

The fits here are tiny (32x32 quick decoders, a few steps, a few dozen simulated participants, a flow of a
few weights): they test the machinery, not the estimator's quality (docs/fit.md measures that).
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from rhi.master.cosim import ConfigError
from rhi.master.fit.calibration import (coverage, rank_bins, rank_histogram, rank_tests_verdict, sbc_ranks,
                                    uniformity)
from rhi.master.fit.data import read_data

ROOT = Path(__file__).resolve().parents[1]


def test_sbc_ranks_by_hand():
    samples = np.array([[[0.1, 5.0], [0.4, 1.0], [0.3, 2.0]],      # participant 0: L = 3 samples of 2 parameters
                        [[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]])
    truths = np.array([[0.35, 0.5], [9.0, -1.0]])
    # below 0.35: 0.1, 0.3 -> 2; below 0.5: none -> 0; below 9: all 3; below -1: none
    assert sbc_ranks(samples, truths).tolist() == [[2, 0], [3, 0]]
    assert rank_bins(99, 100) == 20 and rank_bins(99, 50) == 10 and rank_bins(3, 2) == 1
    ranks = np.array([[0], [1], [2], [3], [3], [99]])
    assert rank_histogram(ranks, 99, 10)[:, 0].tolist() == [5, 0, 0, 0, 0, 0, 0, 0, 0, 1]  # 10 rank values per bin


def test_coverage_is_read_off_the_ranks_by_hand():
    """L = 9 samples 1..9: at 50 % k = floor(10 * 0.5 / 2) = 2, so a truth is inside when 2 to 7 samples lie
    below it (between the 2nd smallest and the 2nd largest, 2 and 8); at 90 % k = 0: every truth."""
    samples = np.arange(1.0, 10.0)[None, :, None].repeat(6, axis=0)
    truths = np.array([[0.5], [1.5], [2.5], [5.5], [7.5], [8.5]])  # 0, 1, 2, 5, 7, 8 samples below
    assert coverage(samples, truths, 0.5)[0] == 3 / 6 and coverage(samples, truths, 0.9)[0] == 1.0


def test_calibration_of_an_exact_conjugate_posterior():
    """theta ~ N(0, 1), x | theta ~ N(theta, s^2): the posterior is N(x / (1 + s^2), s^2 / (1 + s^2)). Exact
    posterior samples must cover at the nominal rates and give uniform ranks; a posterior too narrow must not."""
    rng = np.random.default_rng(0)
    count, draws, s = 2000, 99, 0.5
    theta = rng.standard_normal((count, 1))
    x = theta + s * rng.standard_normal((count, 1))
    mean, sd = x / (1 + s**2), np.sqrt(s**2 / (1 + s**2))
    exact = mean[:, None, :] + sd * rng.standard_normal((count, draws, 1))
    for level in (0.5, 0.9):
        # the interval between the k-th smallest and largest of 99 samples covers exactly the level (k = 25, 5);
        # the tolerance is 4 binomial sds of the share over 2000 participants
        tolerance = 4 * np.sqrt(level * (1 - level) / count)
        assert abs(coverage(exact, theta, level)[0] - level) < tolerance
    result = uniformity(sbc_ranks(exact, theta), draws)
    assert result["bins"] == 20 and result["chisquare_p"][0] > 1e-3 and result["ks_p"][0] > 1e-3
    narrow = mean[:, None, :] + 0.3 * sd * rng.standard_normal((count, draws, 1))  # overconfident
    assert coverage(narrow, theta, 0.9)[0] < 0.6
    assert uniformity(sbc_ranks(narrow, theta), draws)["chisquare_p"][0] < 1e-6
    # chisquare against the histogram by hand
    counts = rank_histogram(sbc_ranks(exact, theta), draws, 20)[:, 0]
    by_hand = ((counts - count / 20) ** 2 / (count / 20)).sum()
    assert result["chisquare"][0] == pytest.approx(by_hand, rel=1e-12)
    assert result["chisquare_p"][0] == pytest.approx(stats.chi2.sf(by_hand, 19), rel=1e-9)


def test_the_rank_tests_verdict_is_bonferroni_s_and_holds_its_family_wise_rate():
    """By hand: 8 tests, threshold 0.05/8; a chi-square without bins (NaN) is not one of them. Then the rate, by
    simulation: 4 parameters whose ranks are exactly uniform (each rank a fresh uniform draw of 0..L, as a
    calibrated posterior gives), 200 participants, 600 fits. The family's rejection rate must be at most 0.05
    plus 4 binomial sds of a share over 600 fits (0.036); the tests judged one by one at 0.05 must reject
    more often than that bound, and an overconfident posterior's family must be rejected."""
    verdict = rank_tests_verdict([0.196, 0.047, 0.795, 0.348], [0.450, 0.146, 0.796, 0.680])
    assert (verdict["tests"], verdict["threshold"], verdict["smallest_p"], verdict["rejected"]) == (8, 0.05 / 8,
                                                                                                     0.047, False)
    assert rank_tests_verdict([0.5, 0.006], [0.9, 0.7])["rejected"]  # 0.006 < 0.05/4
    assert rank_tests_verdict([np.nan], [0.03]) == {"tests": 1, "alpha": 0.05, "threshold": 0.05, "smallest_p": 0.03,
                                                    "rejected": True}
    rng = np.random.default_rng(1)
    family, one_by_one = [], []
    for _ in range(600):
        result = uniformity(rng.integers(0, 100, size=(200, 4)), 99)
        family.append(rank_tests_verdict(result["chisquare_p"], result["ks_p"])["rejected"])
        one_by_one.append(min(result["chisquare_p"].min(), result["ks_p"].min()) < 0.05)
    # 4 sds, not 3: both p-values are asymptotic, and each test alone rejects exactly uniform ranks a little
    # more often than its level (at 0.00625: chi-square 0.0069, KS 0.0073 of 12 000 tests, 1 and 1.4 sds over)
    bound = 0.05 + 4 * np.sqrt(0.05 * 0.95 / 600)
    assert np.mean(family) <= bound < np.mean(one_by_one)
    count, draws = 200, 99
    theta = rng.standard_normal((count, 4))
    narrow = theta[:, None, :] + 0.5 * rng.standard_normal((count, draws, 4))  # truth + noise: a posterior too narrow
    narrow += rng.standard_normal((count, 1, 4))  # ... around a noisy centre of sd 1
    result = uniformity(sbc_ranks(narrow, theta), draws)
    assert rank_tests_verdict(result["chisquare_p"], result["ks_p"])["rejected"]


def write(path, text):
    path.write_text(text)
    return path


def test_data_file_summaries_and_refusals(tmp_path):
    data = read_data(write(tmp_path / "d.csv", "# source: a note, with commas\nparticipant,condition,stimulation,drift_cm\n"
                                             "a,left,sync,-2\n# a comment\na,left,sync,-4\na,left,async,0.5\n"
                                             "b,left,async,1\nb,left,sync,-1\n"))
    assert data.participants == ["a", "b"] and data.cells == [("left", "async"), ("left", "sync")]
    assert data.observed.tolist() == [[0.5, -3.0], [1.0, -1.0]] and data.counts.tolist() == [[1, 2], [1, 1]]
    offsets = read_data(write(tmp_path / "o.csv", "participant,offset_m,delay_s,time_s,drift_cm,force_n\n"
                                                  "p,-0.15,0,30,-2,-0.1\n"))
    assert offsets.conditions == {"offset_-0.15_m": -0.15} and offsets.stimulations == {"delay_0_s": 0.0}
    assert offsets.time_s == 30.0 and offsets.measures == ["drift_cm", "force_n"]
    bad = {"participant,condition,stimulation,drift_cm,mood\n": "unknown column 'mood'",
           "participant,condition,stimulation,drift_cm\na,left,sync,\n": "line 2: empty value in column drift_cm",
           "participant,condition,stimulation,drift_cm\na,left,sync,big\n": "line 2: column drift_cm = 'big' is not",
           "participant,condition,stimulation,drift_cm\na,left,sync,1\nb,left,async,1\n":
               "participant a has no row for the design cell left/async",
           "participant,condition,offset_m,stimulation,drift_cm\n": "exactly one of the columns condition and offset_m",
           "participant,condition,stimulation,drift_cm\na,left,sync,nan\n": "is not a finite number"}
    for text, message in bad.items():
        with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
            read_data(write(tmp_path / "bad.csv", text))


FIT = """
[experiment]
steps = {steps}
[decoder]
fast = true
[fit]
quick = true
simulations = {simulations}
calibration = {calibration}
seed = 3
participants_per_batch = 5
workers = 1
posterior_samples = 50
calibration_samples = 9
predictive_draws = 2
predictive_participants = 1
[fit.noise]
drift_cm = 0.01
[fit.estimator]
hidden_features = 8
transforms = 1
max_epochs = 8
batch_size = 10
threads = 1
[fit.parameters."decoder.visual_variance"]
prior = "log-uniform"
low = 5.0
high = 80.0
[fit.parameters.brain.proprioceptive_variance]
prior = "normal"
mean = 1.0
sd = 0.3
low = 0.5
high = 2.0
"""
DATA = "participant,condition,stimulation,drift_cm,force_n\np1,left,sync,-0.3,-0.02\np1,left,async,-0.01,0.0\n"


def rhi(*arguments, cwd, env=None):
    environment = {**os.environ, **(env or {}),
                   "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-m", "rhi", *arguments], capture_output=True, text=True, cwd=cwd,
                          env=environment, timeout=300)


def test_bad_data_and_fit_files_are_one_line_exit_2_nothing_written(tmp_path, capsys):
    write(tmp_path / "fit.toml", FIT.format(steps=5, simulations=20, calibration=0))
    write(tmp_path / "good.csv", DATA)
    write(tmp_path / "bad.csv", DATA.replace("-0.3", "oops"))
    write(tmp_path / "typo.toml", FIT.format(steps=5, simulations=20, calibration=0).replace("low = 5.0", "lo = 5.0"))
    write(tmp_path / "key.toml", FIT.format(steps=5, simulations=20, calibration=0).replace(
        '"decoder.visual_variance"', '"brain.gama0"'))
    before = sorted(p.name for p in tmp_path.iterdir())
    cases = [(("--data", "bad.csv", "--config", "fit.toml"), "bad.csv line 2: column drift_cm = 'oops' is not a number"),
             (("--data", "good.csv", "--config", "key.toml"), "unknown config key fit.parameters.brain.gama0 (did you mean"),
             (("--data", "good.csv", "--config", "typo.toml"), "unknown fit key fit.parameters.decoder.visual_variance.lo"),
             (("--data", "none.csv", "--config", "fit.toml"), "none.csv does not exist")]
    for number, (arguments, message) in enumerate(cases):
        if number < 1:  # the console script in a process of its own
            result = rhi("fit", *arguments, "--out", "out", cwd=tmp_path)
            status, stderr = result.returncode, result.stderr
        else:  # the same entry point in this process (a subprocess costs seconds of imports)
            from rhi.master.commands.cli import main

            status = main(["fit", *(str(tmp_path / a) if a.endswith((".csv", ".toml")) else a for a in arguments),
                           "--out", str(tmp_path / "out")])
            stderr = capsys.readouterr().err
        lines = stderr.splitlines()
        assert status == 2 and len(lines) == 1, stderr[-2000:]
        assert lines[0].startswith("rhi fit: error: ") and message in lines[0], lines[0]
        assert "Traceback" not in stderr
        assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing half-written


def test_a_batch_of_several_configurations_equals_each_alone(quick_cache, monkeypatch):
    """Two points differing in per-trial parameters, run in one lockstep batch, get their own numbers: each
    trial equals the same trial run in a batch of its point alone (the exact mode: no shared linearisations;
    a batch's float32 sums depend on its size, so the reference batch has the same size: the other point's
    trials as partners with its own values)."""
    from rhi.master import config as configuration
    from rhi.master.sweeps import plan as sweeps
    from rhi.master.sweeps.runner import run_chunk

    monkeypatch.setenv("RHI_CACHE", str(quick_cache))
    base = configuration.load(quick=True, overrides={"experiment.steps": 30, "experiment.decoders": ["conv"],
                                                     "experiment.conditions": ["left"], "decoder.fast": False})
    points = [{"brain.gamma0": 0.01, "decoder.visual_variance": 20.0},
              {"brain.gamma0": 0.3, "decoder.visual_variance": 8.0}]
    sweep = sweeps.build(base, points, points_per_batch=2)
    assert len(sweep.chunks) == 1 and len(sweep.chunks[0]) == 4
    members = [sweep.trials[p] for p in sweep.chunks[0]]
    together = run_chunk(sweep.configs[0], members, [sweep.configs[t.point] for t in members])
    for number in (0, 1):
        alone = sweeps.build(base, [points[number], {**points[number], "experiment.seed": 99}], points_per_batch=2)
        mine = [alone.trials[p] for p in alone.chunks[0]]
        reference = run_chunk(alone.configs[0], mine, [alone.configs[t.point] for t in mine])
        for trial, record in zip(members, together):
            if trial.point == number:
                twin = next(r for t, r in zip(mine, reference) if t.point == 0 and t.stimulation == trial.stimulation)
                assert record["outcome"]["drift_cm"] == twin["outcome"]["drift_cm"]
                assert record["outcome"]["gamma_final"] == twin["outcome"]["gamma_final"]
    drifts = {(t.point, t.stimulation): r["outcome"]["drift_cm"] for t, r in zip(members, together)}
    assert drifts[(0, "sync")] != drifts[(1, "sync")]  # the parameters reached their own trials


def test_a_tiny_fit_end_to_end_killed_and_resumed(quick_cache, tmp_path, monkeypatch, capsys):
    from rhi.master.commands.cli import main

    monkeypatch.setenv("RHI_CACHE", str(quick_cache))
    write(tmp_path / "fit.toml", FIT.format(steps=8, simulations=20, calibration=10))
    write(tmp_path / "data.csv", DATA)
    out = tmp_path / "out"
    command = ["fit", "--data", str(tmp_path / "data.csv"), "--config", str(tmp_path / "fit.toml"), "--out", str(out)]
    assert main(command) == 0
    run = json.loads((out / "run.json").read_text())
    assert run["simulations"] == {**run["simulations"], "participants": 30, "trials": 60, "trials_run_now": 60}
    assert run["estimator"]["hidden_features"] == 8 and run["seeds"]["fit"] == 3
    posterior = (out / "posterior.csv").read_bytes()
    header = posterior.decode().splitlines()[0]
    assert header == "participant,sample,decoder.visual_variance,brain.proprioceptive_variance"
    values = np.loadtxt(out / "posterior.csv", delimiter=",", skiprows=1, usecols=(2, 3))
    assert len(values) == 50 and (values[:, 0] >= 5).all() and (values[:, 0] <= 80).all()
    assert (values[:, 1] >= 0.5).all() and (values[:, 1] <= 2.0).all()  # the prior's bounds hold
    for name in ("estimates.csv", "calibration.csv", "recovery.csv", "held_out.csv", "predictive.csv",
                 "figures/calibration.png", "figures/posterior_predictive.png", "estimator.pt"):
        assert (out / name).exists(), name
    # a kill: some trial records never written, the outputs after the simulations never written
    trials = sorted((out / "simulations" / "trials").glob("*.json"))
    for path in trials[::7]:
        path.unlink()
    for name in ("estimator.pt", "posterior.csv", "run.json"):
        (out / name).unlink()
    # run again, with a second participant of the same design: the same simulations and estimator serve it
    write(tmp_path / "data.csv", DATA + "".join(DATA.replace("p1", "p2").replace("-0.3", "-0.1").splitlines(True)[1:]))
    assert main(command) == 0
    rerun = json.loads((out / "run.json").read_text())
    assert rerun["simulations"]["trials_run_now"] == len(trials[::7])  # only the missing ones were written
    assert rerun["participants"] == ["p1", "p2"]
    again = (out / "posterior.csv").read_bytes()
    assert again[:len(posterior)] == posterior  # p1's: the same simulations, seed and weights, the same bytes
    assert len(again.splitlines()) == 2 * len(posterior.splitlines()) - 1
    # another fit in the same folder is refused, before anything is written
    write(tmp_path / "other.toml", FIT.format(steps=9, simulations=20, calibration=10))
    assert main([*command[:4], str(tmp_path / "other.toml"), *command[5:]]) == 2
    assert "holds a different fit" in capsys.readouterr().err


def test_a_fit_of_some_of_the_data_s_measures_checks_its_posterior_on_those(quick_cache, tmp_path, monkeypatch):
    """fit.measures = ["drift_cm"] of data with drift and force: the estimator and the posterior predictive check
    see the two cells' drifts only."""
    from rhi.master.commands.cli import main

    monkeypatch.setenv("RHI_CACHE", str(quick_cache))
    write(tmp_path / "fit.toml", FIT.format(steps=8, simulations=10, calibration=0).replace(
        "[fit]\n", '[fit]\nmeasures = ["drift_cm"]\n'))
    write(tmp_path / "data.csv", DATA)
    out = tmp_path / "out"
    assert main(["fit", "--data", str(tmp_path / "data.csv"), "--config", str(tmp_path / "fit.toml"),
                 "--out", str(out)]) == 0
    assert json.loads((out / "run.json").read_text())["statistics"] == ["drift_cm[left/async]", "drift_cm[left/sync]"]
    predictive = (out / "predictive.csv").read_text()
    assert "drift_cm[left/sync]" in predictive and "force_n" not in predictive


def test_fit_file_refusals(tmp_path):
    from rhi.master.fit.plan import read_plan

    data = read_data(write(tmp_path / "d.csv", DATA))
    good = FIT.format(steps=5, simulations=20, calibration=0)
    plan = read_plan(write(tmp_path / "f.toml", good), data)
    assert [p.key for p in plan.parameters] == ["decoder.visual_variance", "brain.proprioceptive_variance"]
    assert plan.base["experiment"]["decoders"] == ["conv"] and plan.base["experiment"]["conditions"] == ["left"]
    assert plan.measures == ["drift_cm", "force_n"] and plan.noise == {"drift_cm": 0.01, "force_n": 0.0}
    bad = {"[experiment]\nsteps = 5\n": "has no [fit] table",
           good.replace('prior = "log-uniform"', 'prior = "cauchy"'): "prior = 'cauchy' is not one of",
           good.replace("sd = 0.3\n", ""): "a normal prior needs sd",
           good.replace("low = 5.0", "low = 0.0"): "a log-uniform prior needs low > 0",
           good.replace('"decoder.visual_variance"', '"experiment.steps"'): "not a parameter a fit can vary",
           good.replace("[decoder]", '[experiment]\ndecoders = ["conv", "vae"]\n[decoder]').replace(
               "[experiment]\nsteps", "[stimulus]\nperiod = 2.0\n#"): "a fit simulates one decoder",
           good.replace("high = 2.0", "high = 0.4"): "low must be below high",
           good.replace("simulations = 20", "simulations = 3"): "fit.simulations must be at least 10",
           good.replace("[fit.noise]\ndrift_cm = 0.01", "[fit.noise]\ndrift = 0.01"): "unknown fit key fit.noise.drift",
           good.replace("[fit.estimator]", '[fit.estimator]\nspace = "curved"'):
               "fit.estimator.space = 'curved' is not one of bounded, unconstrained",
           good.replace("[fit.estimator]", '[fit.estimator]\nstatistics = "log"'):
               "fit.estimator.statistics = 'log' is not one of z-score, normal-scores",
           good.replace("seed = 3", 'seed = 3\ncalibration_design = "sobol"'):
               "fit.calibration_design = 'sobol' is not one of random, latin-hypercube",
           # a value the fit's design replaces (trials per cell are fit.trials_per_cell) is refused all the same
           good.replace("[experiment]\nsteps = 5", "[experiment]\nsteps = 5\ntrials = -1"):
               "experiment.trials must be at least 1, got -1"}
    for text, message in bad.items():
        with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("(", r"\(")):
            read_plan(write(tmp_path / "bad.toml", text), data)
    with pytest.raises(ConfigError, match="condition 'far' is not defined"):
        read_plan(write(tmp_path / "f.toml", good), read_data(write(tmp_path / "far.csv", DATA.replace("left", "far"))))


def test_a_latin_hypercube_holds_one_held_out_truth_in_each_stratum_of_every_prior(tmp_path):
    """fit.calibration_design = "latin-hypercube": the training rows are the random design's; the held-out rows'
    prior distribution function values, F(v), fall one in each [k/n, (k+1)/n) (F by scipy, independently of the
    quantile functions the draws went through). An explicit "random" is the fit of no key at all."""
    from rhi.master.fit.plan import Parameter, draw_participants, read_plan
    from rhi.master.fit.run import fingerprint

    parameters = [Parameter("a", "log-uniform", 5.0, 80.0), Parameter("b", "uniform", 0.05, 0.5),
                  Parameter("c", "normal", 0.0, 3.0, mean=1.0, sd=2.0), Parameter("d", "normal", mean=-1.0, sd=0.5)]
    settings = {"simulations": 30, "calibration": 40, "seed": 7}
    random = draw_participants(parameters, {**settings, "calibration_design": "random"})
    latin = draw_participants(parameters, {**settings, "calibration_design": "latin-hypercube"})
    assert np.array_equal(latin[:30], random[:30]) and not np.array_equal(latin[30:], random[30:])
    held = latin[30:]
    cdf = [(held[:, 0] - np.log(5.0)) / (np.log(80.0) - np.log(5.0)), (held[:, 1] - 0.05) / 0.45,
           stats.truncnorm.cdf(held[:, 2], -0.5, 1.0, loc=1.0, scale=2.0), stats.norm.cdf(held[:, 3], -1.0, 0.5)]
    for column in cdf:
        # a value within float rounding of a stratum's edge could land in the next one: none is this close
        assert np.min(np.abs(column * 40 - np.round(column * 40))) > 1e-9
        assert sorted(np.floor(column * 40).astype(int)) == list(range(40))

    data = read_data(write(tmp_path / "d.csv", DATA))
    good = FIT.format(steps=5, simulations=20, calibration=4)
    plain = read_plan(write(tmp_path / "f.toml", good), data)
    named = read_plan(write(tmp_path / "g.toml", good.replace("seed = 3", 'seed = 3\ncalibration_design = "random"')),
                      data)
    assert fingerprint(plain, "sweep") == fingerprint(named, "sweep")


def test_per_trial_parameters_of_a_batch_of_configurations():
    """wiring.parameters (the task's and the model's) give each trial its own values where trials carry them, and
    the configuration's own (a scalar, as before) where none differs; brain.coupling_sd is derived per trial."""
    from rhi.master.tasks.illusion import make_trial
    from rhi.master import config as configuration
    from rhi.master.models import causal
    from rhi.master.config.sources import batchable_keys, parameters

    base = configuration.load(quick=True, model_name="causal")
    assert {"decoder.visual_variance", "brain.sync_sd", "causal.peripersonal_sd",
            "causal.timing_noise_sd"} <= batchable_keys(base)
    assert "experiment.steps" not in batchable_keys(base) and "body.substeps" not in batchable_keys(base)
    own = [(("brain.sync_sd", 0.1), ("causal.peripersonal_sd", 0.15), ("decoder.visual_variance", 20.0)),
           (("brain.sync_sd", 0.3), ("causal.peripersonal_sd", 0.3), ("decoder.visual_variance", 20.0))]
    trials = [make_trial(base, "conv", "left", "sync", 0, overrides) for overrides in own]
    given = parameters(trials, base)
    assert given["brain.sync_sd"].tolist() == [0.1, 0.3]
    assert "brain.gamma0" not in batchable_keys(base)  # the causal brain has no gamma floor: not fitted there
    assert given["decoder.visual_variance"] == 20.0  # the same for both: the configuration's scalar
    assert np.array_equal(given["brain.coupling_sd"], np.stack([causal.coupling_sd(0.15), causal.coupling_sd(0.3)]))
    plain = parameters([make_trial(base, "conv", "left", "sync", 0)], base)
    assert np.array_equal(plain["brain.coupling_sd"], causal.coupling_sd(base["causal"]["peripersonal_sd"]))


def test_an_ensemble_is_the_equal_mixture_of_its_members_and_reloads_as_saved(tmp_path):
    """fit.estimator.ensemble = 2: two members from two seeds; the ensemble's density is the mean of the
    members' densities (by hand, from each member's own posterior), and estimator.pt gives back the same
    members (the same samples)."""
    import types

    import torch

    from rhi.master.fit import inference
    from rhi.master.fit.plan import ESTIMATOR_DEFAULTS, Parameter
    from rhi.master.fit.run import load_or_train

    parameters = [Parameter("a", "uniform", -3.0, 3.0), Parameter("b", "uniform", -3.0, 3.0)]
    rng = np.random.default_rng(1)
    theta = rng.uniform(-3, 3, (200, 2))
    x = theta + 0.5 * rng.standard_normal((200, 2))
    settings = {**ESTIMATOR_DEFAULTS, "hidden_features": 4, "transforms": 1, "max_epochs": 3, "threads": 1,
                "ensemble": 2}
    plan = types.SimpleNamespace(parameters=parameters, settings={"seed": 0}, estimator=settings)
    members, summary = load_or_train(plan, theta, x, tmp_path / "estimator.pt", "identity")
    assert len(members) == 2 and len(summary["members"]) == 2
    weights = [m.state_dict() for m in members]
    assert any(not torch.equal(weights[0][k], weights[1][k]) for k in weights[0])  # two seeds, two members
    ensemble = inference.posterior(parameters, members, settings, x)
    points = torch.tensor([[0.0, 0.0], [1.0, -2.0], [2.5, 2.5]])
    observed = torch.tensor([0.5, -0.5])
    # unnormalised (norm_posterior=False): sbi's correction for mass leaking out of the prior's support is itself
    # estimated by sampling, a random number per call
    each = torch.stack([inference.posterior(parameters, [m], settings, x).log_prob(points, x=observed,
                                                                                norm_posterior=False)
                        for m in members])
    by_hand = torch.logsumexp(each, dim=0) - np.log(2.0)
    # float32 densities of the same networks, summed in another order: 1e-5 is some 100 float32 ulps of ~1
    assert torch.allclose(ensemble.log_prob(points, x=observed, norm_posterior=False), by_hand, atol=1e-5)
    reloaded, _ = load_or_train(plan, theta, x, tmp_path / "estimator.pt", "identity")
    assert np.array_equal(inference.sample(inference.posterior(parameters, reloaded, settings, x), observed.numpy(), 50, 7),
                          inference.sample(ensemble, observed.numpy(), 50, 7))


def test_the_unconstrained_space_by_hand():
    """fit.estimator.space = "unconstrained": a uniform on (a, b) maps by the logit z = log((v - a)/(b - v)) and its
    density there is the logistic sigma(z)(1 - sigma(z)); a normal bounded below maps by z = log(v - low), density
    N(v) e^z / (1 - Phi(low)); an unbounded normal is unchanged. Samples come back in the inference space."""
    import torch

    from rhi.master.fit import inference
    from rhi.master.fit.plan import ESTIMATOR_DEFAULTS, Parameter

    parameters = [Parameter("a", "uniform", 0.05, 0.5), Parameter("b", "log-uniform", 5.0, 80.0),
                  Parameter("c", "normal", 0.0, np.inf, 1.0, 0.5), Parameter("d", "normal", mean=0.0, sd=2.0)]
    settings = {**ESTIMATOR_DEFAULTS, "space": "unconstrained"}
    v = np.array([[0.1, np.log(20.0), 1.3, -0.7], [0.45, np.log(6.0), 0.2, 3.0]])
    z = inference.to_flow(parameters, settings, v).double().numpy()
    a, b = np.log(5.0), np.log(80.0)
    expected = np.stack([np.log((v[:, 0] - 0.05) / (0.5 - v[:, 0])), np.log((v[:, 1] - a) / (b - v[:, 1])),
                         np.log(v[:, 2]), v[:, 3]], axis=1)
    assert np.allclose(z, expected, rtol=1e-6, atol=1e-6)  # float32 transforms of O(1) values: 1e-6 is ~10 ulps
    by_hand = (stats.logistic.logpdf(z[:, 0]) + stats.logistic.logpdf(z[:, 1])  # sigma(z)(1 - sigma(z))
               + stats.norm.logpdf(v[:, 2], 1.0, 0.5) + z[:, 2] - stats.norm.logsf(0.0, 1.0, 0.5)
               + stats.norm.logpdf(v[:, 3], 0.0, 2.0))
    density = inference.flow_prior(parameters, settings).log_prob(torch.as_tensor(z, dtype=torch.float32))
    assert np.allclose(density.double().numpy(), by_hand, atol=1e-4)  # float32 sums of four log densities of O(10)
    bounded = inference.to_flow(parameters, {**ESTIMATOR_DEFAULTS, "space": "bounded"}, v).double().numpy()
    assert bounded == pytest.approx(v, rel=6e-8)  # the values themselves, rounded to float32 (half an ulp: 6e-8)

    rng = np.random.default_rng(2)   # a tiny estimator trained in that space samples inside every bound
    theta = inference.torch_prior(parameters).sample((200,)).double().numpy()
    x = theta + 0.3 * rng.standard_normal(theta.shape)
    estimator, _ = inference.train(parameters, theta, x, {**settings, "hidden_features": 4, "transforms": 1,
                                                          "max_epochs": 3, "threads": 1}, seed=0)
    drawn = inference.sample(inference.posterior(parameters, [estimator], settings, x), x[0], 500, 3)
    assert drawn.shape == (500, 4)
    assert np.all((drawn[:, 0] > 0.05) & (drawn[:, 0] < 0.5) & (drawn[:, 1] > a) & (drawn[:, 1] < b) & (drawn[:, 2] > 0))


def test_the_normal_scores_by_hand():
    """fit.estimator.statistics = "normal-scores": the k-th smallest of n training values goes to Phi^-1((k - 1/2)/n),
    a value between two of them linearly between their scores, one beyond them to the end's score; "z-score"
    leaves the statistics as they are. The posterior's samples are those of the scaled statistics."""
    from rhi.master.fit import inference
    from rhi.master.fit.plan import ESTIMATOR_DEFAULTS, Parameter

    training = np.array([[3.0, 0.5], [1.0, -1.0], [2.0, 0.0], [10.0, 7.0]])
    scores = stats.norm.ppf([1 / 8, 3 / 8, 5 / 8, 7 / 8])  # n = 4
    scale = inference.statistics_scale({"statistics": "normal-scores"}, training)
    x = np.array([[2.0, 7.0], [2.5, -0.5], [100.0, -5.0], [1.0, 0.25]])
    expected = np.array([[scores[1], scores[3]], [(scores[1] + scores[2]) / 2, (scores[0] + scores[1]) / 2],
                         [scores[3], scores[0]], [scores[0], (scores[1] + scores[2]) / 2]])
    # a linear interpolation of float64 scores: 1e-12 is a few thousand ulps of O(1)
    assert np.allclose(scale(x), expected, rtol=0, atol=1e-12)
    assert scale(x[0]).shape == (2,) and np.allclose(scale(x[None]), expected[None], rtol=0, atol=1e-12)
    assert np.array_equal(inference.statistics_scale({"statistics": "z-score"}, training)(x), x)
    with pytest.raises(ValueError, match="3 statistics given to an estimator trained on 2"):
        scale(np.zeros(3))

    parameters = [Parameter("a", "uniform", -3.0, 3.0), Parameter("b", "uniform", -3.0, 3.0)]
    rng = np.random.default_rng(3)
    theta = rng.uniform(-3, 3, (200, 2))
    statistics = np.exp(theta + 0.3 * rng.standard_normal((200, 2)))  # spanning decades
    settings = {**ESTIMATOR_DEFAULTS, "statistics": "normal-scores", "hidden_features": 4, "transforms": 1,
                "max_epochs": 3, "threads": 1}
    estimator, _ = inference.train(parameters, theta, statistics, settings, seed=0)
    scaled = inference.posterior(parameters, [estimator], settings, statistics)
    plain = inference.posterior(parameters, [estimator], {**settings, "statistics": "z-score"}, statistics)
    observed = statistics[5]
    assert np.array_equal(inference.sample(scaled, observed, 50, 4),
                          inference.sample(plain, inference.statistics_scale(settings, statistics)(observed), 50, 4))


def test_the_fit_in_memory_gives_rhi_fit_s_simulations_and_a_posterior_within_the_prior(quick_cache, tmp_path,
                                                                                         monkeypatch):
    """rhi.master.fit.memory: simulate the training participants of a tiny fit here, nothing written; their statistics
    are the ones `rhi fit` computed from its simulations/ folder, bit for bit (the same lockstep batches and
    seeds); train and sample give (count, parameters) draws inside the priors' supports."""
    from rhi.master.commands.cli import main
    from rhi.master.fit import memory
    from rhi.master.fit.plan import draw_participants, read_plan
    from rhi.master.fit.simulate import participants_sweep, statistics, with_noise
    from rhi.master.sweeps.folder import read_records

    monkeypatch.setenv("RHI_CACHE", str(quick_cache))
    write(tmp_path / "fit.toml", FIT.format(steps=8, simulations=20, calibration=0))
    write(tmp_path / "data.csv", DATA)
    assert main(["fit", "--data", str(tmp_path / "data.csv"), "--config", str(tmp_path / "fit.toml"), "--out",
                 str(tmp_path / "out")]) == 0
    data = read_data(str(tmp_path / "data.csv"))
    plan = read_plan(str(tmp_path / "fit.toml"), data)
    theta = draw_participants(plan.parameters, plan.settings)
    sweep = participants_sweep(plan, theta, "prior")
    folder = with_noise(statistics(sweep, read_records(tmp_path / "out" / "simulations", sweep), data, plan.measures),
                        data, plan.measures, plan.noise, plan.settings["seed"], "prior")
    here = memory.simulate(plan, data, theta)
    assert here.shape == (20, 4) and np.array_equal(here, folder)  # 2 cells x 2 measures; bitwise
    samples = memory.sample(plan, memory.train(plan, theta, here), here[0], 30, seed=5)
    assert samples.shape == (30, 2)
    assert np.all((samples[:, 0] >= 5.0) & (samples[:, 0] <= 80.0))  # decoder.visual_variance: log-uniform [5, 80]
    assert np.all((samples[:, 1] >= 0.5) & (samples[:, 1] <= 2.0))  # proprioceptive variance: normal in [0.5, 2]
