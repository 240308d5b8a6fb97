"""The ownership model: each mechanism against a hand computation (the evidence of a touch, gamma after n touches
in closed form, the realignment against the exact exponential), the brain run step by step on given inputs, the
wiring (no simulator position reaches the brain), and its settings (the free rates' placeholders, refusals).

Truth: scipy.stats' densities and plain float arithmetic written out here, not the functions under test."""
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import multivariate_normal, norm, uniform

from rhi.components.body.kinematics import FOREARM, UPPER_ARM, forward
from rhi.components.brain import ownership_inference as oi
from rhi.components.brain import realignment
from rhi.components.brain.ownership_brain import NOISE_STREAM, OwnershipBrain
from rhi.components.vision import pose_encoder as pe
from rhi.components.vision.networks import Encoder, preset
from tests.toys import assert_reads_no_simulator_position
from rhi.master import config as configuration
from rhi.master import models
from rhi.master.cosim import ConfigError
from rhi.master.models.ownership import FREE_PARAMETERS
from rhi.master.tasks.illusion import wiring

STEP = 0.02
ROOT = Path(__file__).resolve().parents[1]


def logit(p):
    return math.log(p / (1 - p))


def logistic(x):
    return 1 / (1 + math.exp(-x))


@pytest.mark.parametrize("delay", [0.0, 0.05, -0.12, 0.5, 0.9])
def test_the_evidence_of_a_touch_is_the_log_ratio_of_scipy_densities(delay):
    sd, period = 0.089, 2.0
    hand = norm(0.0, sd).logpdf(delay) - uniform(-period / 2, period).logpdf(delay)
    got = oi.asynchrony_log_likelihood_ratio(np.array([delay]), np.array([sd]), np.array([period]))
    assert got[0] == pytest.approx(hand, rel=1e-13, abs=1e-13)  # rounding of a few terms
    if delay == 0.0:  # the peak: -log(sd sqrt(2 pi)) + log T = 2.19 nats, about 1.7 nats on average over the noise
        assert got[0] == pytest.approx(-math.log(sd * math.sqrt(2 * math.pi)) + math.log(period), rel=1e-13)


@pytest.mark.parametrize("seen, felt", [((150.0, -80.0), (140.0, -90.0)), ((59.2, -28.1), (147.7, -91.2)),
                                        ((160.0, -120.0), (160.0, -120.0))])
def test_the_evidence_of_a_touchs_place_is_the_log_ratio_of_scipy_densities(seen, felt):
    spread = 0.127
    got = oi.spatial_log_likelihood_ratio(
        oi.hand_separation(np.array([seen]), np.array([felt]), UPPER_ARM, FOREARM), spread, UPPER_ARM + FOREARM)
    assert got[0] == pytest.approx(place_evidence(seen, felt, spread), rel=1e-12, abs=1e-12)  # a few roundings


def test_the_peripersonal_spread_makes_a_touch_at_the_boundary_neutral():
    reach = UPPER_ARM + FOREARM
    spread = oi.peripersonal_sd_from_boundary(0.30, reach)
    assert spread < 0.30 / math.sqrt(2)  # the smaller root
    # the log ratio at the boundary is 0 to the root finder's tolerance (a relative 4 eps on sigma: ~1e-15 nats)
    assert oi.spatial_log_likelihood_ratio(0.30, spread, reach) == pytest.approx(0.0, abs=1e-12)
    # and the evidence falls with the distance: for one cause within, against beyond
    near, far = oi.spatial_log_likelihood_ratio(np.array([0.15, 0.45]), spread, reach)
    assert near > 0 > far
    with pytest.raises(ValueError, match="reach > boundary"):  # L <= D sqrt(e): no spread is neutral there
        oi.peripersonal_sd_from_boundary(0.30, 0.30 * math.sqrt(math.e))


def bayes_by_hand(gamma, log_ratio):
    """Bayes' rule written out: p L / (p L + 1 - p)."""
    ratio = math.exp(log_ratio)
    return gamma * ratio / (gamma * ratio + 1 - gamma)


def test_gamma_after_n_touches_is_the_closed_form_without_switching():
    from rhi.components.brain.body_inference import hazard_predict, posterior

    prior, evidence = 0.01, np.array([1.3, 2.1, -0.4, 1.9, 0.7])
    gamma = np.array([prior])
    for value in evidence:
        for _ in range(100):  # 2 s between touches, no switching: the state holds
            gamma = hazard_predict(gamma, prior, np.inf, STEP)
        gamma = posterior(gamma, np.exp([value]))
    # logit gamma_n = logit gamma_0 + sum of the touches' log ratios
    assert gamma[0] == pytest.approx(logistic(logit(prior) + evidence.sum()), rel=1e-13)


def test_gamma_with_switching_is_the_recursion_written_out():
    from rhi.components.brain.body_inference import hazard_predict, posterior

    prior, rate, period, evidence = 0.01, 0.05, 2.0, [2.0, 2.0, 2.0, 2.0]
    gamma, hand = np.array([prior]), prior
    for value in evidence:
        for _ in range(round(period / STEP)):
            gamma = hazard_predict(gamma, prior, 1 / rate, STEP)
        hand = prior + (hand - prior) * math.exp(-rate * period)  # the chain relaxed over one period exactly
        hand = bayes_by_hand(hand, value)
        gamma = posterior(gamma, np.exp([value]))
    assert gamma[0] == pytest.approx(hand, rel=1e-12)  # 400 steps of rounding


def test_the_onset_is_kept_from_the_first_crossing():
    onset = oi.ownership_onset(np.array([np.nan, np.nan, 3.0]), np.array([0.4, 0.5, 0.9]), 7.0)
    assert np.isnan(onset[0]) and onset[1] == 7.0 and onset[2] == 3.0


def test_the_realignment_step_is_the_exact_exponential():
    seen, felt = np.array([[150.0, -80.0]]), np.array([[140.0, -90.0]])
    target = realignment.realignment_target(seen, felt, np.array([0.39]), np.array([0.73]))
    assert target == pytest.approx(np.array([[0.39 * 0.73 * 10.0, 0.39 * 0.73 * 10.0]]), rel=1e-15)
    b, rate = np.array([[1.0, -2.0]]), np.array([0.04])
    for _ in range(1500):  # 30 s
        b = oi.relaxation_step(b, target, rate, STEP)
    exact = target + (np.array([[1.0, -2.0]]) - target) * math.exp(-0.04 * 30.0)
    assert b == pytest.approx(exact, rel=1e-12)  # 1500 roundings
    assert oi.relaxation_step(b, target, np.array([0.0]), STEP) == pytest.approx(b, rel=0)  # k = 0: held


def test_the_belief_rate_is_minus_the_gradient_of_the_free_energy():
    s_p, b, mu, variance = np.array([[140.0, -90.0]]), np.array([[2.0, 1.0]]), np.array([[141.0, -88.0]]), 1.5
    rate = realignment.belief_rate(s_p, b, mu, np.array([variance]))
    assert rate == pytest.approx(np.array([[(142.0 - 141.0) / 1.5, (-89.0 + 88.0) / 1.5]]), rel=1e-15)
    eps = 1e-6
    for j in range(2):
        up, down = mu.copy(), mu.copy()
        up[0, j] += eps
        down[0, j] -= eps
        slope = (realignment.free_energy(s_p, b, up, np.array([variance]))
                 - realignment.free_energy(s_p, b, down, np.array([variance]))) / (2 * eps)
        assert -slope[0] == pytest.approx(rate[0, j], rel=1e-6)  # central difference of a quadratic


# What a test here takes where it names no value: the slow mechanisms off, as the hand computations assume (the
# brain's own starts are the model's fitted settings, master/models/ownership.toml).
BY_HAND = {"coupling_prior": 0.73, "coupling_window_sd": 1.0, "counter_evidence_leak": 0.0, "switching_rate": 0.0,
           "proprioceptive_fading_rate": 0.0, "realignment_rate": 0.0}


def brain(batch, **given):
    """An ownership brain of ``batch`` trials, initialized with ``given`` parameters (the rest :data:`BY_HAND`'s,
    else its defaults)."""
    made = OwnershipBrain()
    made.instantiate(batch)
    for name, value in {"mu0": (140.0, -90.0), **BY_HAND, **given}.items():
        made.set(name, value)
    made.initialize()
    return made


def step(made, t, s_p, seen, visual=-np.inf, tactile=-np.inf):
    for name, value in (("q_shoulder", s_p[0]), ("q_elbow", s_p[1]), ("seen_pose", seen),
                        ("visual_time", visual), ("tactile_time", tactile)):
        made.set(name, np.broadcast_to(np.asarray(value, float), made.values[name].shape).copy())
    made.step(t, STEP)


def place_evidence(seen, felt, spread):
    """The spatial log ratio by hand: scipy's 2-D normal density of the hands' offset (the body's own forward
    kinematics) over the uniform density of a disc of the arm's reach."""
    offset = np.subtract(forward(*seen), forward(*felt))
    reach = UPPER_ARM + FOREARM
    return multivariate_normal(np.zeros(2), spread**2 * np.eye(2)).logpdf(offset) + math.log(math.pi * reach**2)


def test_the_brain_accumulates_each_touch_with_its_own_noise_and_records_the_onset():
    sd, window, period, seed, prior, spread = 0.2, 1.0, 2.0, 7, 0.01, 0.12
    made = brain(1, timing_sd=sd, coupling_window_sd=window, stroke_period=period, participant_seed=seed,
                 ownership_prior=prior, coupling_prior=0.73, switching_rate=0.0, realignment_rate=0.0,
                 counter_evidence_leak=0.0, peripersonal_sd=spread)
    noise = np.random.default_rng([seed, NOISE_STREAM])
    place = place_evidence((150.0, -80.0), (140.0, -90.0), spread)
    odds_gamma, counter, onset, touches = logit(prior), 0.0, None, 0
    for k in range(round(12.0 / STEP)):
        t = k * STEP
        touch = k > 0 and k % round(period / STEP) == 0  # a visual and a tactile event 0.03 s apart
        visual = (k // 100) * 2.0 if k >= 100 else -np.inf
        tactile = visual - 0.03 if k >= 100 else -np.inf
        step(made, t, (140.0, -90.0), (150.0, -80.0), visual, tactile)
        if touch:
            touches += 1
            perceived = 0.03 + sd * noise.standard_normal()
            # the timing belief: the touch's timing in ownership's window; the counter-evidence: in the coupling's
            odds_gamma += norm(0, sd).logpdf(perceived) + math.log(period)
            counter += norm(0, window).logpdf(perceived) + math.log(period)
            if onset is None and logistic(odds_gamma + place) >= 0.5:
                onset = t + STEP
        assert made.values["timing_belief"][0] == pytest.approx(logistic(odds_gamma), rel=1e-12), t
        # ownership: the timing belief with the seen hand's place, counted once (before any touch too)
        assert made.values["gamma"][0] == pytest.approx(logistic(odds_gamma + place), rel=1e-12), t
        assert made.values["counter_evidence"][0] == pytest.approx(counter, rel=1e-12, abs=1e-14), t
        # the coupling: its prior, the seen hand's place once, and the touches' accumulated evidence
        assert made.values["coupling"][0] == pytest.approx(logistic(logit(0.73) + place + counter), rel=1e-12), t
    assert touches == 5
    shown = made.values["ownership_onset"][0]
    assert (onset is None and np.isnan(shown)) or shown == pytest.approx(onset, abs=1e-12)


def test_the_brain_realigns_toward_the_seen_arm_without_touch_and_the_belief_follows():
    w, prior, rate = 0.39, 0.73, 0.05
    made = brain(1, realignment_weight=w, coupling_prior=prior, realignment_rate=rate, switching_rate=0.02,
                 ownership_prior=0.01)
    s_p, seen = np.array([140.0, -90.0]), np.array([150.0, -84.0])
    for k in range(round(20.0 / STEP)):
        step(made, k * STEP, s_p, seen)
    # no touch: the coupling is its prior with the seen hand's place, b = w rho d (1 - exp(-k t))
    coupling = logistic(logit(prior) + place_evidence(seen, s_p, made.values["peripersonal_sd"][0]))
    assert made.values["coupling"][0] == pytest.approx(coupling, rel=1e-13)
    ownership = logistic(logit(0.01) + place_evidence(seen, s_p, made.values["peripersonal_sd"][0]))
    assert made.values["gamma"][0] == pytest.approx(ownership, rel=1e-13)  # the seen hand's place alone
    exact = w * coupling * (seen - s_p) * (1 - math.exp(-rate * 20.0))
    assert made.values["realignment"][0] == pytest.approx(exact, rel=1e-12)
    # the belief lags b by about Sigma_p = 1 s: mu - s_p within b's change over a few seconds
    assert made.values["mu"][0] - s_p == pytest.approx(exact, rel=0.1)


def test_one_asynchronous_touch_takes_ownership_away_and_moves_the_coupling_by_its_own_window_only():
    made = brain(1, participant_seed=3, timing_sd=0.2, coupling_window_sd=1.0, stroke_period=2.0, ownership_prior=0.01)
    step(made, 0.0, (140.0, -90.0), (140.0, -90.0), 2.0, 1.4)  # 0.6 s apart, the hands at one place
    perceived = 0.6 + 0.2 * np.random.default_rng([3, NOISE_STREAM]).standard_normal()
    assert made.values["counter_evidence"][0] == pytest.approx(norm(0, 1.0).logpdf(perceived) + math.log(2.0),
                                                               rel=1e-12)
    assert -1.0 < made.values["counter_evidence"][0] < 0.0  # a wide window: a fraction of a nat against unity
    assert made.values["gamma"][0] < 0.01  # ownership's narrow window: evidence against


@pytest.fixture(scope="module")
def tiny_ownership(tmp_path_factory):
    """A configuration of the ownership model at 16 px with an untrained tiny pose encoder."""
    folder = tmp_path_factory.mktemp("pose")
    path = folder / "pose.pt"
    pe.save_encoder(path, pe.PoseModel(Encoder(preset("tiny"), 16), (147.7, -91.2), (40.0, 50.0), (1.0, 1.0)),
                    preset("tiny"), 16)
    return configuration.load(overrides={"experiment.resolution": 16, "experiment.steps": 20, "experiment.trials": 1,
                                         "ownership.conv_pose_encoder": str(path),
                                         "ownership.vae_pose_encoder": str(path)}, model_name="ownership")


def test_the_ownership_brain_never_reads_a_simulator_position(tiny_ownership):
    from rhi.components.body import kinematics
    from rhi.components.vision.component import Decoder, GenerativeModel
    from rhi.components.vision.networks import build

    model = GenerativeModel(build("conv", "tiny", 16).decoder, kinematics.REST_POSE, (40.0, 50.0), {"kind": "conv"})
    assert_reads_no_simulator_position(wiring.build_system(Decoder(model, threads=1), tiny_ownership), OwnershipBrain())


def test_the_free_parameters_are_the_shipped_fits_adopted_values():
    """master/models/ownership.toml holds each free parameter at the adopted point of the shipped population fits
    (point.csv of each of FIT_FOLDERS, the drift's and the onset's, written by rhi fit: the key, or its population
    median), to the 3 significant digits written; each fitted by exactly one of them, so the individual fit's
    medians (docs/fit/human/ownership_rohde2011/) are no longer adopted."""
    import csv

    from rhi.master.models.ownership import FIT_FOLDERS

    adopted = {}
    for folder in FIT_FOLDERS:
        with open(ROOT / folder / "point.csv") as file:
            point = {row["parameter"].removeprefix("population.").removesuffix(".median"): float(row["value"])
                     for row in csv.DictReader(file) if not row["parameter"].endswith(("logit_sd", "log_sd"))}
        assert not set(point) & set(adopted)
        adopted.update(point)
    assert set(adopted) == set(FREE_PARAMETERS)
    config = configuration.load(model_name="ownership")
    for key, value in adopted.items():
        table, _, name = key.partition(".")
        assert config[table][name] == pytest.approx(value, rel=5e-3)  # 3 significant digits: half a unit of the third
    assert configuration.load()["brain"]["gamma0"] == 0.01  # the paper's model keeps the paper's prior


def test_the_drift_depends_on_neither_of_the_onset_fits_parameters(tiny_ownership):
    """Why the onset is fitted apart from the drift (docs/fit/human/ownership_onset.toml): ownership gamma does not
    enter the realignment, so the ownership prior and the switching rate leave the belief, the action and the
    coupling the same to the bit, while ownership itself moves."""
    from rhi.components.body import kinematics
    from rhi.components.vision.component import Decoder, GenerativeModel
    from rhi.components.vision.networks import build
    from rhi.master.config.protocol import make_trial

    runs = []
    for gamma0, rate in ((0.000227, 0.255), (0.01, 0.0319)):
        config = configuration.merge(tiny_ownership, {"experiment": {"steps": 150}, "brain": {"gamma0": gamma0},
                                                      "ownership": {"switching_rate": rate}})
        decoder = Decoder(GenerativeModel(build("conv", "tiny", 16).decoder, kinematics.REST_POSE, (40.0, 50.0),
                                          {"kind": "conv"}), threads=1)
        trials = [make_trial(config, "conv", "left", stimulation, 0, ()) for stimulation in ("sync", "async")]
        runs.append(wiring.run_batch(decoder, trials, config).values)
    for name in ("brain.mu", "brain.action_rate", "body.force_x", "brain.coupling", "brain.realignment"):
        np.testing.assert_array_equal(runs[0][name], runs[1][name])
    assert not np.array_equal(runs[0]["brain.gamma"], runs[1]["brain.gamma"])


def test_the_model_takes_its_prior_and_period_from_one_source_each():
    sources = models.get("ownership").parameter_sources
    assert sources["brain.ownership_prior"] == "brain.gamma0" and sources["brain.stroke_period"] == "stimulus.period"
    assert "ownership" not in configuration.load()  # the defaults stay the paper's model


@pytest.mark.parametrize("key, value, message", [
    ("ownership.coupling_window_sd", -0.5, "ownership.coupling_window_sd"),
    ("ownership.counter_evidence_leak", -1.0, "ownership.counter_evidence_leak"),
    ("ownership.switching_rate", -1.0, "ownership.switching_rate"),
    ("ownership.coupling_prior", 1.0, "ownership.coupling_prior"),
    ("ownership.realignment_weight", 1.5, "ownership.realignment_weight"),
    ("ownership.peripersonal_boundary", -0.3, "ownership.peripersonal_boundary must be a positive, finite distance"),
    # L = 0.729 m < 0.5 m sqrt(e): no spread makes a touch 50 cm away neutral
    ("ownership.peripersonal_boundary", 0.5,
     r"ownership.peripersonal_boundary: no peripersonal sd .* reach > boundary"),
])
def test_bad_settings_are_one_line_before_any_work(key, value, message):
    from rhi.master.config.sources import check_parameters

    with pytest.raises(ConfigError, match=message) as caught:
        check_parameters(configuration.load(overrides={key: value}, model_name="ownership"))
    assert "\n" not in str(caught.value)


def test_trials_record_the_onset_as_the_first_time_gamma_reaches_one_half(tiny_ownership):
    """The model's own measures (Model.measures) reach the per-step table: ``ownership_onset_s`` is NaN until the
    step at which the recorded gamma first reaches 1/2, and that step's time from then on (truth: the gamma column
    read here); ``coupling`` is the brain's output as recorded."""
    from rhi.components.body import kinematics
    from rhi.components.vision.component import Decoder, GenerativeModel
    from rhi.components.vision.networks import build
    from rhi.master.config.protocol import make_trial
    from rhi.master.tasks.illusion.measures import measures

    config = configuration.merge(tiny_ownership, {"experiment": {"steps": 400},  # the paper's prior: an onset in 8 s
                                                  "brain": {"gamma0": 0.01}, "ownership": {"switching_rate": 0.0319},
                                                  "stimulations": {"sync": {"delay_min": 0.0, "delay_max": 0.0}}})
    decoder = Decoder(GenerativeModel(build("conv", "tiny", 16).decoder, kinematics.REST_POSE, (40.0, 50.0),
                                      {"kind": "conv"}), threads=1)
    trials = [make_trial(config, "conv", "left", "sync", index, ()) for index in range(2)]
    result = wiring.run_batch(decoder, trials, config)
    table = measures(result, models.of(config))
    assert set(models.of(config).measures) <= set(table)
    for trial in range(2):
        crossed = np.flatnonzero(table["gamma"][:, trial] >= 0.5)
        assert crossed.size  # 4 simultaneous touches in 8 s, about 1.7 nats each (docs/model.md); 4.6 needed
        first = crossed[0]
        assert np.isnan(table["ownership_onset_s"][:first, trial]).all()
        assert (table["ownership_onset_s"][first:, trial] == result.times[first]).all()
    assert np.array_equal(table["coupling"], result.values["brain.coupling"])


def test_the_shipped_population_s_spreads_are_the_fits_adopted_spreads():
    """docs/population/ownership.toml holds each spread at the adopted point of the population fit that fitted it
    (point.csv's population.KEY.logit_sd or .log_sd), to the 3 significant digits written; its medians are the
    model's own (no median of its own in the file)."""
    import csv

    from rhi.master.config import population

    from rhi.master.models.ownership import FIT_FOLDERS

    fitted = {}
    for folder in FIT_FOLDERS:
        with open(ROOT / folder / "point.csv") as file:
            fitted.update({row["parameter"]: float(row["value"]) for row in csv.DictReader(file)
                           if row["parameter"].endswith(("logit_sd", "log_sd"))})
    config = configuration.load(ROOT / "docs/population/ownership.toml", model_name="ownership")
    entries = population.entries(config)
    assert {f"population.{key}.{spread}" for key, entry in entries.items()
            for spread in ("logit_sd", "log_sd") if spread in entry} == set(fitted)
    for name, value in fitted.items():
        key, spread = name.removeprefix("population.").rsplit(".", 1)
        assert entries[key][spread] == pytest.approx(value, rel=5e-3) and "median" not in entries[key]
