"""The ownership model's second-version mechanisms, each against a hand computation: a hand must be seen (no pull
and no touch evidence while none is, and through the whole system: rubber arm hidden, no touch, no drift); the
counter-evidence that accumulates and leaks, and the coupling it leaves; proprioception fading at rest and the
seen hand's weight; ownership before touch from the seen hand's place.

Truth: plain float arithmetic written out here, not the functions under test."""
import math

import numpy as np
import pytest
from scipy.stats import norm
from test_ownership_model import brain, place_evidence

from rhi.components.brain import ownership_inference as oi
from rhi.components.brain import realignment
from rhi.components.brain.ownership_brain import NOISE_STREAM
from rhi.master import config as configuration
from rhi.master import models
from rhi.master.config.protocol import make_trial
from rhi.master.tasks.illusion import wiring
from rhi.master.tasks.illusion.measures import measures

STEP = 0.02




def step(made, t, s_p, seen, visual=-np.inf, tactile=-np.inf, visible=1.0):
    for name, value in (("q_shoulder", s_p[0]), ("q_elbow", s_p[1]), ("seen_pose", seen),
                        ("visual_time", visual), ("tactile_time", tactile), ("arm_visible", visible)):
        made.set(name, np.broadcast_to(np.asarray(value, float), made.values[name].shape).copy())
    made.step(t, STEP)


def test_no_seen_hand_no_pull_and_no_touch_evidence():
    # two trials: the arm in view and not; the same phantom reading x_v and the same synchronous touches
    made = brain(2, realignment_rate=0.1, switching_rate=0.0, coupling_prior=0.9, participant_seed=[1, 1],
                 ownership_prior=0.01)
    s_p, phantom = np.array([140.0, -90.0]), np.array([150.0, -80.0])
    for k in range(round(10.0 / STEP)):
        visual = 2.0 * (k // 100) if k >= 100 else -np.inf
        step(made, k * STEP, s_p, phantom, visual, visual - 0.02, visible=[1.0, 0.0])
    b = made.values["realignment"]
    assert np.abs(b[0]).max() > 1.0  # in view: b moves toward w rho (x_v - s_p), several degrees
    assert np.array_equal(b[1], [0.0, 0.0]) and np.allclose(made.values["mu"][1], s_p, atol=1e-12)
    assert made.values["gamma"][1] == pytest.approx(0.01, rel=1e-14)  # no touch of a seen hand: no evidence
    assert made.values["gamma"][0] > 0.5


def test_the_realignment_holds_while_the_hand_is_out_of_view():
    # in view for 5 s, then hidden for 5 s: b as the exact exponential, then held (rate k v = 0)
    w, rho, k = 0.39, 0.8, 0.2
    made = brain(1, realignment_weight=w, coupling_prior=rho, realignment_rate=k, switching_rate=0.01)
    s_p, seen = np.array([140.0, -90.0]), np.array([150.0, -84.0])
    for i in range(round(10.0 / STEP)):
        step(made, i * STEP, s_p, seen, visible=1.0 if i < 250 else 0.0)
    coupling = logistic(logit(rho) + place_evidence(seen, s_p, made.values["peripersonal_sd"][0]))
    exact = w * coupling * (seen - s_p) * (1.0 - math.exp(-k * 5.0))
    assert made.values["realignment"][0] == pytest.approx(exact, rel=1e-12)


def test_seen_hand_is_the_scene_s_signal():
    assert oi.seen_hand(np.array([1.0, 0.0, 0.9, 0.1])).tolist() == [1.0, 0.0, 1.0, 0.0]


def tiny_decoder():
    from rhi.components.body import kinematics
    from rhi.components.vision.component import Decoder, GenerativeModel
    from rhi.components.vision.networks import build

    return Decoder(GenerativeModel(build("conv", "tiny", 16).decoder, kinematics.REST_POSE, (40.0, 50.0),
                                   {"kind": "conv"}), threads=1)


def test_rubber_arm_hidden_and_no_touch_gives_no_drift():
    """The whole system with the model's shipped 64 px pose encoder: the scene declares the arm hidden
    (rubber_arm.hidden_conditions) to the brain, which then has no seen hand to pull toward; its drift is at most
    5 % of the synchronous drift with the arm in view (the issue's criterion; here it is 0 to the float: b never
    moves), after 10 s at 15 cm."""
    config = configuration.load(overrides={"experiment.steps": 500, "experiment.trials": 1, "conditions.dark": 0.15,
                                           "rubber_arm.hidden_conditions": ["dark"]}, model_name="ownership")
    config = configuration.merge(config, {"stimulations": {"vision": {"delay_min": 0.0, "delay_max": 0.1,
                                                                      "touch": False}}})
    trials = [make_trial(config, "conv", "right", "sync", 0), make_trial(config, "conv", "dark", "vision", 0)]
    assert [t.arm_visible for t in trials] == [True, False]
    result = wiring.run_batch(tiny_decoder(), trials, config)  # the decoder is left out: no pixel term
    drift = measures(result, models.of(config))["drift_cm"][-1]
    assert drift[0] > 0.5  # toward the rubber hand: the synchronous drift is real (1.7 cm at 10 s, docs/model.md)
    assert abs(drift[1]) <= 0.05 * drift[0]


def logit(p):
    return math.log(p / (1 - p))


def logistic(x):
    return 1 / (1 + math.exp(-x))


def test_the_counter_evidence_leaks_as_the_exact_exponential():
    c = np.array([-3.0, 2.0])
    for _ in range(500):  # 10 s
        c = oi.relaxation_step(c, 0.0, np.array([0.05, 0.0]), STEP)
    assert c[0] == pytest.approx(-3.0 * math.exp(-0.05 * 10.0), rel=1e-13)  # 500 roundings
    assert c[1] == 2.0  # no leak: kept


def test_the_coupling_is_its_prior_with_the_place_and_the_counter_evidence_in_log_odds():
    got = oi.coupling_belief(np.array([0.9, 0.3, 0.9]), np.array([1.5, 0.0, 0.0]), np.array([-4.0, 0.7, -800.0]))
    assert got[0] == pytest.approx(logistic(logit(0.9) + 1.5 - 4.0), rel=1e-14)
    assert got[1] == pytest.approx(logistic(logit(0.3) + 0.7), rel=1e-14)
    assert got[2] == 0.0 or got[2] < 1e-300  # no overflow far out


def test_a_pause_discounts_the_asynchronous_evidence_and_continuous_stroking_accumulates_it():
    """Asynchronous touches 0.5 s late every 2 s for 20 s, then a 20 s pause, then 20 s more: C by hand (each
    touch's log ratio under the coupling's window, the leak between), the same noise draws."""
    sd, window, leak, period = 0.2, 0.8, 0.05, 2.0
    made = brain(1, timing_sd=sd, coupling_window_sd=window, counter_evidence_leak=leak, stroke_period=period,
                 participant_seed=5, switching_rate=0.0)
    noise = np.random.default_rng([5, NOISE_STREAM])
    felt = np.array([140.0, -90.0])
    counter, last_touch, visual, through_first = 0.0, 0.0, -np.inf, None
    for k in range(round(60.0 / STEP)):
        t_end = (k + 1) * STEP
        stroking = not (20.0 < t_end <= 40.0)
        if stroking and k > 0 and (k + 1) % round(period / STEP) == 0:  # a visual event at the step's end
            visual = t_end
            counter *= math.exp(-leak * (t_end - last_touch))
            counter += norm(0, window).logpdf(-0.5 + sd * noise.standard_normal()) + math.log(period)
            last_touch = t_end
        step(made, k * STEP, felt, felt, visual, visual + 0.5 if np.isfinite(visual) else -np.inf)
        if abs(t_end - 20.0) < 1e-9:
            through_first = made.values["counter_evidence"][0]
        if abs(t_end - 40.0) < 1e-9:  # 20 s of pause: discounted by exp(-20 kappa)
            assert made.values["counter_evidence"][0] == pytest.approx(through_first * math.exp(-leak * 20.0),
                                                                       rel=1e-10)
    counter *= math.exp(-leak * (60.0 - last_touch))
    assert made.values["counter_evidence"][0] == pytest.approx(counter, rel=1e-10)  # 3000 roundings
    assert through_first < -1.0  # ten touches, a fraction of a nat each


def test_the_felt_variance_grows_linearly_at_rest_and_a_movement_refreshes_it():
    base, rate = np.array([1.0, 2.0]), np.array([0.05, 0.0])
    variance = base.copy()
    for _ in range(1000):  # 20 s at rest
        variance = realignment.felt_variance_step(variance, base, rate, np.zeros(2), STEP)
    assert variance[0] == pytest.approx(1.0 * (1 + 0.05 * 20.0), rel=1e-12) and variance[1] == 2.0
    # a movement of 0.5 deg (summed over the joints) after a step of growth: the excess times exp(-0.5 / sqrt(1))
    moved = realignment.felt_variance_step(variance, base, rate, np.array([0.5, 0.5]), STEP)
    assert moved[0] == pytest.approx(1.0 + (1.0 + 0.05 * STEP) * math.exp(-0.5), rel=1e-13)


def test_the_seen_hand_s_weight_is_reliability_weighting_anchored_at_the_measured_weight():
    # at Sigma_p0 the weight is w0; Sigma_v = Sigma_p0 (1 - w0) / w0 = 1.5 (1 - 0.4) / 0.4 = 2.25 deg^2
    w = realignment.visual_weight(np.array([1.5, 3.0, 1e9]), np.array([1.5, 1.5, 1.5]), np.array([0.4, 0.4, 0.4]))
    assert w[0] == pytest.approx(0.4, rel=1e-14)
    assert w[1] == pytest.approx(3.0 / (3.0 + 2.25), rel=1e-14)
    assert w[2] == pytest.approx(1.0, rel=1e-8)


def test_a_resting_arm_s_drift_builds_up_as_its_proprioception_fades():
    """The brain, the arm still and no touch: Sigma_p(t) = Sigma_p0 (1 + phi t), and b the exact exponential step of a
    target that grows with w(t), written out here."""
    w0, prior, k, phi, sigma0 = 0.39, 0.8, 0.1, 0.02, 1.0
    made = brain(1, realignment_weight=w0, coupling_prior=prior, realignment_rate=k, proprioceptive_fading_rate=phi,
                 proprioceptive_variance=sigma0)
    s_p, seen = np.array([140.0, -90.0]), np.array([150.0, -84.0])
    rho = logistic(logit(prior) + place_evidence(seen, s_p, made.values["peripersonal_sd"][0]))
    b, seen_variance = np.zeros(2), sigma0 * (1 - w0) / w0
    for n in range(round(30.0 / STEP)):
        step(made, n * STEP, s_p, seen)
        felt = sigma0 * (1 + phi * n * STEP)
        target = felt / (felt + seen_variance) * rho * (seen - s_p)
        b = target + (b - target) * math.exp(-k * STEP)
    assert made.values["felt_variance"][0] == pytest.approx(sigma0 * (1 + phi * 30.0), rel=1e-12)
    assert made.values["realignment"][0] == pytest.approx(b, rel=1e-11)  # 1500 steps of rounding
    assert abs(b[0]) > w0 * rho * 10.0 * (1 - math.exp(-k * 30.0))  # more than with a constant Sigma_p
