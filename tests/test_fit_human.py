"""rhi fit on group data: a data row's own observation noise (MEASURE_sem) read, refused and added with that sd, and
the ownership model's fit of Rohde et al. 2011 (docs/fit/human/ownership_rohde2011.toml) checked against its
sources and run end to end at a tiny size.

Truth: numpy's normal draws from the fit's documented seed, the chi-square distribution of a normal sample's
variance, FREE_PARAMETERS (master/models/ownership.py), and the protocol file docs/fit/human/rohde2011.toml.
"""
import csv
import json
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from rhi.master.cosim import ConfigError
from rhi.master.fit.data import read_data
from rhi.master.fit.plan import read_plan
from rhi.master.fit.simulate import with_noise
from rhi.master.models.ownership import FREE_PARAMETERS

ROOT = Path(__file__).resolve().parents[1]
HUMAN = ROOT / "docs" / "fit" / "human"
SEM = {"async": 0.69, "sync": 1.59, "vision": 1.10}  # cm, Rohde et al. 2011 Exp. 2 (docs/fit/human/rohde2011.csv)
HEADER = "participant,condition,stimulation,drift_cm,drift_cm_sem,force_n\n"


def write(path, text):
    path.write_text(text)
    return path


def test_a_noise_column_gives_each_cell_its_sd_and_bad_values_are_one_line(tmp_path):
    data = read_data(write(tmp_path / "d.csv", HEADER + "a,left,sync,-2,1.5,0\na,left,async,0,0.25,0\n"
                                                         "b,left,sync,-1,1.5,0\nb,left,async,1,0.25,0\n"))
    assert data.cells == [("left", "async"), ("left", "sync")] and data.noise["drift_cm"].tolist() == [0.25, 1.5]
    # drift from its column, force from fit.noise.force_n (absent: 0), cell-major as the statistics
    assert data.noise_sd(["drift_cm", "force_n"], {"force_n": 0.1}).tolist() == [0.25, 0.1, 1.5, 0.1]
    assert read_data(write(tmp_path / "plain.csv", "participant,condition,stimulation,drift_cm\na,left,sync,1\n")
                     ).noise == {}
    bad = {HEADER + "a,left,sync,-2,-0.5,0\n": "line 2: column drift_cm_sem = -0.5 must be a standard error >= 0",
           HEADER + "a,left,sync,-2,inf,0\n": "line 2: column drift_cm_sem = 'inf' is not a finite number",
           HEADER + "a,left,sync,-2,1001,0\n": "drift_cm_sem = 1001 must be a standard error >= 0 and at most 1000",
           "participant,condition,stimulation,drift_cm,force_n_sem\na,left,sync,-2,0.1\n":
               "column force_n_sem without its measure force_n",
           HEADER + "a,left,sync,-2,1.5,0\nb,left,sync,-1,1.4,0\n":
               "line 3: column drift_cm_sem = 1.4 differs from line 2's 1.5 for the design cell left/sync"}
    for text, message in bad.items():
        with pytest.raises(ConfigError, match=re.escape(message)):
            read_data(write(tmp_path / "bad.csv", text))
    fit = write(tmp_path / "fit.toml", '[fit]\n[fit.noise]\ndrift_cm = 0.5\n[fit.parameters."decoder.visual_variance"]\n'
                                       'prior = "uniform"\nlow = 5.0\nhigh = 80.0\n')
    with pytest.raises(ConfigError, match="fit.noise.drift_cm: the data's column drift_cm_sem gives each cell's"):
        read_plan(str(fit), data)


def test_the_noise_added_to_each_cell_has_the_row_s_sd():
    """With the fit's seed, the noise is numpy's standard normal draw from default_rng([seed, 1, sum of the stream's
    character codes]) times each cell's SEM (to 1e-12); over n = 20000 draws each cell's sample sd s satisfies
    (n - 1) s^2 / sd^2 ~ chi-square(n - 1), so s / sd lies in the central 99.9 % interval of that law's
    sqrt(q / (n - 1)), about 1 +- 0.023."""
    data = read_data(HUMAN / "rohde2011.csv")
    sd = np.array([SEM[s] for _, s in data.cells])
    n = 20000
    noisy = with_noise(np.zeros((n, 3)), data, ["drift_cm"], {}, 7, "prior")
    expected = np.random.default_rng([7, 1, sum(map(ord, "prior"))]).standard_normal((n, 3)) * sd
    assert np.allclose(noisy, expected, rtol=0, atol=1e-12)
    low, high = (np.sqrt(stats.chi2.ppf(q, n - 1) / (n - 1)) for q in (0.0005, 0.9995))
    ratio = noisy.std(axis=0, ddof=1) / sd
    assert np.all((ratio > low) & (ratio < high)), (ratio, low, high)
    # a NaN (a failed simulated participant) stays NaN; no noise column and no fit.noise: the values unchanged
    assert np.isnan(with_noise(np.full((1, 3), np.nan), data, ["drift_cm"], {}, 7, "prior")).all()
    plain = read_data(HUMAN / "kocur2022.csv")
    assert with_noise(np.ones((2, 1)), plain, ["drift_cm"], {}, 7, "prior").tolist() == [[1.0], [1.0]]


def protocol(path):
    tables = tomllib.loads(Path(path).read_text())
    tables.pop("fit", None)
    return tables


def test_the_ownership_fit_file_fits_the_free_parameters_on_their_priors_over_rohde_s_protocol():
    assert protocol(HUMAN / "ownership_rohde2011.toml") == protocol(HUMAN / "rohde2011.toml")
    data = read_data(HUMAN / "rohde2011.csv")
    plan = read_plan(str(HUMAN / "ownership_rohde2011.toml"), data)
    assert plan.settings["model"] == "ownership"
    assert {p.key: (p.prior, p.low, p.high) for p in plan.parameters} == {  # the prior only the onset fit has
        key: (prior, low, high) for key, (prior, low, high) in FREE_PARAMETERS.items() if key != "brain.gamma0"}
    assert plan.base["experiment"]["steps"] == 6000 and plan.base["conditions"]["rohde"] == -0.17  # 120 s, 17 cm
    assert plan.base["stimulations"]["vision"]["touch"] is False
    assert data.noise_sd(plan.measures, plan.noise).tolist() == [SEM[s] for _, s in data.cells]
    assert data.observed.tolist() == [[-0.98, -5.90, -6.47]]  # async, sync, vision: the group means, cm


@pytest.mark.parametrize("model", ["paper", "causal", "ownership"])
def test_every_default_given_again_as_a_value_is_accepted(model):
    """A batch's per-trial values are merged over its configuration (a fit's draws, a stimulation's own keys): each
    default, the infinite ones included (stimulus.stop_time = inf: the stroking never stops), is a valid value."""
    from rhi.master import config as configuration

    defaults = configuration.load(model_name=model)
    assert configuration.merge(defaults, defaults) == defaults


def tiny_fit(tmp_path, pose_encoder):
    """The shipped fit file at a tiny size: 10 + 3 participants, 8 steps (time_s 0.16 s), 32 px, a flow of a few
    weights; the ownership model's pose encoder an untrained tiny one."""
    text = (HUMAN / "ownership_rohde2011.toml").read_text()
    sizes = {"simulations": 10, "calibration": 3, "participants_per_batch": 13, "posterior_samples": 20,
             "calibration_samples": 9, "predictive_draws": 2}
    for key, value in sizes.items():
        text, count = re.subn(rf"(?m)^{key} = \d+", f"{key} = {value}", text)
        assert count == 1, key
    text = text.replace("[fit]\n", "[fit]\nquick = true\nworkers = 1\n").replace(
        "[fit.estimator]\n", "[fit.estimator]\nhidden_features = 8\ntransforms = 1\nmax_epochs = 8\nbatch_size = 10\n")
    text = text.replace("threads = 2", "threads = 1")
    text += f'\n[ownership]\nconv_pose_encoder = "{pose_encoder}"\n'
    data = (HUMAN / "rohde2011.csv").read_text().replace(",120,", ",0.16,")
    return write(tmp_path / "fit.toml", text), write(tmp_path / "data.csv", data)


def test_a_tiny_ownership_fit_runs_and_adds_each_cell_s_sem(quick_cache, tmp_path, monkeypatch):
    """The whole pipeline on the shipped files, shrunk: the posterior inside the priors; run.json and held_out.csv
    carry each cell's SEM, and the held-out statistics are the simulations' cell means plus numpy's draw of the
    fit's seed times that SEM (to the CSV's 6 significant digits: rtol 1e-5)."""
    from rhi.components.vision import pose_encoder as pe
    from rhi.components.vision.networks import Encoder, preset
    from rhi.master.commands.cli import main
    from rhi.master.fit.plan import draw_participants
    from rhi.master.fit.simulate import participants_sweep, statistics
    from rhi.master.sweeps.folder import read_records

    monkeypatch.setenv("RHI_CACHE", str(quick_cache))
    encoder = tmp_path / "pose.pt"
    pe.save_encoder(encoder, pe.PoseModel(Encoder(preset("tiny"), 32), (147.7, -91.2), (40.0, 50.0), (1.0, 1.0)),
                    preset("tiny"), 32)
    fit, data_path = tiny_fit(tmp_path, encoder)
    out = tmp_path / "out"
    assert main(["fit", "--data", str(data_path), "--config", str(fit), "--out", str(out)]) == 0
    run = json.loads((out / "run.json").read_text())
    assert run["model"] == "ownership" and run["simulations"]["trials"] == 13 * 3
    assert run["cell_noise"] == {f"drift_cm[rohde/{s}]": sd for s, sd in SEM.items()}
    values = np.loadtxt(out / "posterior.csv", delimiter=",", skiprows=1, usecols=(2, 3))
    assert values.shape == (20, 2) and np.all((values >= 1 / 600) & (values <= 1.0))
    # the adopted point is one joint posterior sample: the row of posterior.csv it names (6 significant digits)
    point = list(csv.DictReader((out / "point.csv").open()))
    samples = list(csv.DictReader((out / "posterior.csv").open()))
    assert [r["parameter"] for r in point] == [k for k in FREE_PARAMETERS if k != "brain.gamma0"]
    assert len({r["sample"] for r in point}) == 1
    row = samples[int(point[0]["sample"])]
    assert [float(row[r["parameter"]]) for r in point] == pytest.approx([float(r["value"]) for r in point], rel=1e-5)
    data = read_data(data_path)
    plan = read_plan(str(fit), data)
    sweep = participants_sweep(plan, draw_participants(plan.parameters, plan.settings), "prior")
    clean = statistics(sweep, read_records(out / "simulations", sweep), data, plan.measures)
    sd = np.array([SEM[s] for _, s in data.cells])
    draw = np.random.default_rng([0, 1, sum(map(ord, "prior"))]).standard_normal(clean.shape) * sd
    held = np.genfromtxt(out / "held_out.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    assert held["drift_cm_sem"].tolist() == [SEM[s] for s in held["stimulation"]]
    assert np.allclose(held["drift_cm"].reshape(3, 3), (clean + draw)[10:], rtol=1e-5, atol=1e-12)


def test_the_group_fit_file_fits_a_population_over_rohde_s_protocol_on_means_and_sds():
    """docs/fit/human/ownership_group.toml: Rohde's protocol (the batched arm), studies of n = 10, the medians on
    FREE_PARAMETERS' priors; rohde2011_group.csv: rohde2011.csv's means with sd = SEM sqrt(10), to the 1 um written."""
    group, individual = protocol(HUMAN / "ownership_group.toml"), protocol(HUMAN / "rohde2011.toml")
    assert group.pop("experiment") == {**individual.pop("experiment"), "body": "batched"}
    assert group.pop("population").keys() == {"ownership.coupling_prior", "ownership.realignment_rate"}
    assert group == individual
    data = read_data(HUMAN / "rohde2011_group.csv")
    assert data.measures == ["drift_cm", "drift_cm_sd"] and data.cells == read_data(HUMAN / "rohde2011.csv").cells
    means, sds = data.observed[0, 0::2], data.observed[0, 1::2]
    assert means.tolist() == [-0.98, -5.90, -6.47]  # async, sync, vision, as rohde2011.csv
    assert sds.tolist() == pytest.approx([SEM[s] * 10 ** 0.5 for _, s in data.cells], abs=5e-4)
    plan = read_plan(str(HUMAN / "ownership_group.toml"), data)
    assert plan.settings["model"] == "ownership" and plan.settings["trials_per_cell"] == 10
    priors = {p.key.removeprefix("population.").removesuffix(".median"): (p.prior, p.low, p.high)
              for p in plan.parameters if not p.key.endswith((".logit_sd", ".log_sd"))}
    assert priors == {k: v for k, v in FREE_PARAMETERS.items() if k not in ("ownership.switching_rate", "brain.gamma0")}


def test_the_training_set_is_two_studies_each_under_its_own_protocol():
    """docs/fit/human/training.csv with ownership_training.toml: Rohde's protocol as rohde2011.toml gives it with its
    n = 10; Kocur's 22.5 cm, 180 s and n = 24 (kocur2022.csv's source) as a sync - async contrast whose sd follows
    from the F test (sd = 1.6 / sqrt(F) sqrt(n)); the fit file's priors and population the group fit's."""
    rohde = protocol(HUMAN / "protocols" / "rohde2011_exp2.toml")
    individual = protocol(HUMAN / "rohde2011.toml")
    assert rohde.pop("experiment") == {"trials": 10, **{k: v for k, v in individual.pop("experiment").items()
                                                        if k in ("steps", "probe_times")}}
    assert rohde == individual
    data = read_data(HUMAN / "training.csv")
    assert data.observed[0, :6].tolist() == read_data(HUMAN / "rohde2011_group.csv").observed[0].tolist()
    assert data.cells[3] == ("protocols/kocur2022.toml:kocur", "sync-async")
    assert data.observed[0, 6:].tolist() == [-1.6, pytest.approx(1.6 / 6.591 ** 0.5 * 24 ** 0.5, abs=5e-4)]
    plan = read_plan(str(HUMAN / "ownership_training.toml"), data)
    (kocur_config,) = plan.configs()[1:]
    step = kocur_config["experiment"]["step_size"]
    assert (kocur_config["conditions"]["kocur"], kocur_config["experiment"]["steps"] * step,
            kocur_config["experiment"]["trials"]) == (-0.225, pytest.approx(180.0), 24)
    group = read_plan(str(HUMAN / "ownership_group.toml"), read_data(HUMAN / "rohde2011_group.csv"))
    assert [p.describe() for p in plan.parameters] == [p.describe() for p in group.parameters]
    assert plan.base["population"] == group.base["population"]
    assert {k: v for k, v in plan.settings.items() if k != "trials_per_cell"} == {
        k: v for k, v in group.settings.items() if k != "trials_per_cell"}


def test_the_judged_training_fit_is_the_training_fit_with_a_judgements_error_from_its_source():
    """ownership_training_judged.toml: ownership_training.toml's design, priors and draws, plus each participant's
    error of a judged drift: van Beers et al. 1998's joint-angle sd (0.6-1.1 deg, the midpoint) through the body's
    Jacobian at rest (m/deg), the hand's lateral error, times sqrt(2) for after minus before (to the 1 um written)."""
    from rhi.components.body.kinematics import REST_POSE, jacobian

    data = read_data(HUMAN / "training.csv")
    judged = read_plan(str(HUMAN / "ownership_training_judged.toml"), data)
    plain = read_plan(str(HUMAN / "ownership_training.toml"), data)
    assert (judged.base, judged.designs, judged.settings) == (plain.base, plain.designs, plain.settings)
    assert [p.describe() for p in judged.parameters] == [p.describe() for p in plain.parameters]
    lateral = jacobian(*REST_POSE)[0]  # d(hand x)/d(shoulder, elbow), m/deg
    sd_cm = 100 * 0.85 * float(np.hypot(*lateral)) * 2 ** 0.5
    assert plain.participant_noise == {} and judged.participant_noise == {"drift_cm": pytest.approx(sd_cm, abs=5e-4)}


def test_the_drift_point_that_ships_is_a_prior_draw_of_the_training_fit_and_the_least_miss_of_its_checks():
    """docs/fit/human/ownership_training_screen/ (docs/fit.md, "What ships"): point.csv is the fit's prior draw it
    names (the draws made again from the fit file's seed: the same values to the 6 digits written), and checks.csv's
    z are (mean - observed) / standard error, the standard errors from training.csv by hand (a mean's sd / sqrt n, an
    sd's sd / sqrt(2 (n - 1)); n from the protocol files), the candidate that ships the one whose largest |z| is
    least."""
    from rhi.master.fit.priors import draw_participants

    folder = HUMAN / "ownership_training_screen"
    data = read_data(HUMAN / "training.csv")
    plan = read_plan(str(HUMAN / "ownership_training_judged_1000.toml"), data)
    with open(folder / "point.csv", newline="") as file:
        point = list(csv.DictReader(file))
    draw = {int(row["sample"]) for row in point}
    assert len(draw) == 1
    drawn = draw_participants(plan.parameters, plan.settings)[draw.pop()]
    values = {row["parameter"]: float(row["value"]) for row in point}
    assert set(values) == {p.key for p in plan.parameters}
    for parameter, value in zip(plan.parameters, drawn):
        assert values[parameter.key] == pytest.approx(float(parameter.from_inference(value)), rel=5e-6)

    trials = {"rohde2011_exp2": 10, "kocur2022": 24}
    with open(HUMAN / "training.csv", newline="") as file:
        rows = list(csv.DictReader(line for line in file if not line.startswith("#")))
    expected = {}
    for row in rows:
        n = trials[Path(row["protocol"]).stem]
        cell = f"{row['protocol']}:{row['condition']}/{row['stimulation']}" + \
            (f"-{row['baseline']}" if row["baseline"] else "")
        sd = float(row["drift_cm_sd"])
        expected[f"drift_cm[{cell}]"] = (float(row["drift_cm"]), sd / np.sqrt(n))
        expected[f"drift_cm_sd[{cell}]"] = (sd, sd / np.sqrt(2 * (n - 1)))
    largest = {}
    with open(folder / "checks.csv", newline="") as file:
        for row in csv.DictReader(file):
            observed, error = expected[row["statistic"]]
            assert float(row["observed"]) == observed and float(row["standard_error"]) == pytest.approx(error, rel=1e-3)
            mean = float(row["mean_of_20_studies"])
            z = (mean - observed) / error
            # z is written to 3 significant digits and computed from the mean before it was written to 4: half a
            # unit of each last digit, the mean's through 1/error
            digit = lambda x, figures: 0.5 * 10.0 ** (np.floor(np.log10(abs(x))) - figures + 1)  # noqa: E731
            assert float(row["z"]) == pytest.approx(z, abs=digit(z, 3) + digit(mean, 4) / error)
            largest[row["candidate"]] = max(largest.get(row["candidate"], 0.0), abs(z))
    assert len(largest) == 3 and min(largest, key=largest.get) == f"draw {int(point[0]['sample'])}"
