"""The brain: exact discrete relaxation, step order, causal inference of gamma by hand, the closed-form
fixed point with a linear decoder under the master, batch = single runs, causal inference over space."""
import math

import numpy as np
import pytest

from rhi.components.brain import Brain
from rhi.components.brain.touch_timing import decayed, posterior_common_cause, update_gamma
from rhi.components.component import ComponentError, Status
from rhi.master import System, simulate
from tests.linear_decoder import LinearDecoder
from tests.toys import Constant

from tests.brain_steps import H, advance, normal_pdf, started


# -- integration -------------------------------------------------------------------------------

def test_gamma_zero_relaxes_at_the_exact_discrete_rate():
    s_p, offset, variance = np.array([147.7, -91.2]), np.array([0.3, -0.2]), 0.8
    brain = started(gamma0=0.0, proprioceptive_variance=variance, mu0=s_p + offset,
                    inputs={"q_shoulder": s_p[0], "q_elbow": s_p[1], "visual_drive": [[50.0, -30.0]],
                            "visual_error": 5.0})  # a drive and an error that gamma = 0 must shut out
    mus, actions, energies = [], [], []
    for n in range(100):
        advance(brain, n * H)
        mus.append(brain.get("mu")[0])
        actions.append([brain.get("u_shoulder")[0], brain.get("u_elbow")[0]])
        energies.append(brain.get("free_energy")[0])
    factor = 1 - H / variance  # per step
    n = np.arange(1, 101)[:, None]
    expected_mu = s_p + offset * factor ** n
    np.testing.assert_allclose(np.array(mus) - s_p, expected_mu - s_p, rtol=1e-9, atol=1e-12)
    # a_dot = -(s_p - mu)/Sigma_p with the belief after each update; a is its running sum times dt
    np.testing.assert_allclose(actions, np.cumsum(H * offset * factor ** n / variance, axis=0), rtol=1e-9)
    # F_n is the proprioceptive term at the belief step n started from; the visual term is gated off
    previous = offset * factor ** (n - 1)
    np.testing.assert_allclose(energies, (previous ** 2).sum(axis=1) / (2 * variance), rtol=1e-9)


def test_action_uses_the_belief_after_its_update():
    mu0, s_p, drive, variance, h = np.array([10.0, 20.0]), np.array([10.5, 19.0]), np.array([3.0, -4.0]), 2.0, 0.1
    brain = started(gamma0=1.0, proprioceptive_variance=variance, mu0=mu0,
                    inputs={"q_shoulder": s_p[0], "q_elbow": s_p[1], "visual_drive": [drive], "visual_error": 0.7})
    advance(brain, 0.0, h)
    mu1 = mu0 + h * ((s_p - mu0) / variance + drive)  # gamma = 1
    np.testing.assert_allclose(brain.get("mu")[0], mu1, rtol=1e-15)
    a_dot = -(s_p - mu1) / variance
    a_dot_before = -(s_p - mu0) / variance
    assert np.abs(a_dot - a_dot_before).min() > 0.1  # the two orders are told apart
    np.testing.assert_allclose(brain.get("action_rate")[0], a_dot, rtol=1e-14)
    np.testing.assert_allclose([brain.get("u_shoulder")[0], brain.get("u_elbow")[0]], h * a_dot, rtol=1e-14)
    assert brain.get("free_energy")[0] == pytest.approx(((s_p - mu0) ** 2).sum() / (2 * variance) + 0.7, rel=1e-14)


@pytest.mark.parametrize("limit", [1.0, 0.25])
def test_action_is_clipped_to_its_limit(limit):
    brain = started(mu0=[50.0, -50.0], action_limit=limit, gamma0=0.0)
    for n in range(3):
        advance(brain, n * H)
    # mu above s_p pushes the shoulder up, mu below s_p the elbow down, both past the limit
    assert (brain.get("u_shoulder")[0], brain.get("u_elbow")[0]) == (limit, -limit)


# -- causal inference of gamma ------------------------------------------------------------------

def test_gamma_follows_bayes_and_decay_by_hand():
    brain = started(gamma0=0.01)
    gamma = 0.01

    def bayes(g, delay):
        p1 = normal_pdf(delay)
        return max(0.01, min(1.0, p1 * g / (p1 * g + 0.5 * (1 - g))))

    def decay(g, now, tactile):
        return max(0.01, g * math.exp(-((now - tactile) ** 2 / (1 / H)) * (1 / 80)))

    # visual event alone, no touch yet: gamma holds
    advance(brain, 0.98, visual_time=1.0)
    assert brain.get("gamma")[0] == 0.01
    # its tactile partner 10 ms later: Bayes' rule; F weighs the visual error with this new gamma
    advance(brain, 1.0, tactile_time=1.01, visual_error=2.0)
    gamma = bayes(gamma, 1.0 - 1.01)
    assert gamma > 0.035 and brain.get("gamma")[0] == pytest.approx(gamma, rel=1e-13)
    assert brain.get("free_energy")[0] == pytest.approx(2.0 * gamma, rel=1e-13)  # s_p = mu = 0
    # no new pair: the decay, timed from the last touch to the end of the step
    for t in (1.02, 1.04, 1.5):
        advance(brain, t)
        gamma = decay(gamma, t + H, 1.01)
        assert brain.get("gamma")[0] == pytest.approx(gamma, rel=1e-13)
    # a second synchronous pair, both events seen on the same step
    advance(brain, 2.98, visual_time=3.0, tactile_time=3.0)
    gamma = bayes(gamma, 0.0)
    assert brain.get("gamma")[0] == pytest.approx(gamma, rel=1e-13)
    before = gamma
    # an asynchronous pair (350 ms) lowers it, exactly by Bayes' rule
    advance(brain, 4.98, visual_time=5.0)
    gamma = decay(gamma, 5.0, 3.0)  # the visual event alone decays
    advance(brain, 5.34, tactile_time=5.35)
    gamma = bayes(gamma, -0.35)
    assert gamma < before and brain.get("gamma")[0] == pytest.approx(gamma, rel=1e-13)
    # a very late touch (900 ms) would push it below gamma0: the clamp holds it there
    advance(brain, 6.98, visual_time=7.0)
    advance(brain, 7.88, tactile_time=7.9)
    assert bayes(decay(gamma, 7.0, 5.35), -0.9) == 0.01 and brain.get("gamma")[0] == 0.01


def test_many_synchronous_pairs_multiply_the_odds_and_stay_below_one():
    brain = started(gamma0=0.01)
    odds_ratio = normal_pdf(0.0) / 0.5  # per zero-delay pair, decay aside (both events on one step)
    for k in range(1, 31):
        advance(brain, 2.0 * k - H, visual_time=2.0 * k, tactile_time=2.0 * k)
        gamma = brain.get("gamma")[0]
        if k == 3:
            assert gamma / (1 - gamma) == pytest.approx(0.01 / 0.99 * odds_ratio ** 3, rel=1e-12)
        assert 0.01 <= gamma <= 1.0
    assert gamma > 1 - 1e-12


def test_decay_to_the_floor_and_the_clamp_of_the_update():
    brain = started(gamma0=0.2, decay_rate=100.0)
    advance(brain, 0.0, visual_time=0.01, tactile_time=0.01)
    raised = brain.get("gamma")[0]
    assert raised == pytest.approx(normal_pdf(0) * 0.2 / (normal_pdf(0) * 0.2 + 0.5 * 0.8), rel=1e-13)
    advance(brain, 0.02)
    assert brain.get("gamma")[0] == pytest.approx(raised * math.exp(-(0.03 ** 2) * H * 100), rel=1e-13)
    for n in range(2, 40):
        advance(brain, n * H)
    assert brain.get("gamma")[0] == 0.2  # decayed to the floor gamma0, never below
    clamped = update_gamma(np.array([1.5, 0.5, 0.0]), np.array([False, True, False]), np.zeros(3), np.zeros(3),
                           0.0, H, np.full(3, 0.1))
    assert clamped[0] == 1.0 and clamped[2] == 0.1  # out-of-range values are clamped to [gamma0, 1]
    assert decayed(np.array([0.5]), 3.0, np.array([-np.inf]), H, 0.0)[0] == 0.5  # no touch yet: no decay
    # a certain prior meets a density that underflows to 0: the posterior stays certain, not 0/0
    assert posterior_common_cause(np.array([1.0, 0.5]), np.zeros(2), np.array([10.0, 0.0]), 0.2, 0.5)[0] == 1.0



def test_gamma_without_a_new_pair_is_the_decay_alone_to_the_bit():
    """A step with no new pair skips Bayes' rule: the same bytes as choosing between the two branches element-wise
    (np.where over both, as for a step where some trial has a pair), touched and untouched trials alike."""
    rng = np.random.default_rng(5)
    gamma, tactile = rng.uniform(0.01, 1.0, 8), np.where(np.arange(8) < 3, -np.inf, rng.uniform(0.0, 9.0, 8))
    visual, floor, none = rng.uniform(0.0, 9.0, 8), np.full(8, 0.01), np.zeros(8, bool)
    both = np.clip(np.where(none, posterior_common_cause(gamma, np.zeros(8), np.zeros(8), 0.2, 0.5),
                            decayed(gamma, 10.0, tactile, H, 1.0 / 80.0)), floor, 1.0)
    got = update_gamma(gamma, none, visual, tactile, 10.0, H, floor, 0.2, 0.5, 1.0 / 80.0)
    assert got.tobytes() == both.tobytes()

# -- the master, a linear decoder and the closed-form fixed point ----------------------------------

def test_fixed_point_is_the_precision_weighted_compromise():
    A = np.array([[0.8, 0.1], [-0.3, 0.6], [0.2, -0.5], [0.4, 0.4]])
    b, seen = np.array([0.1, -0.2, 0.3, 0.0]), np.array([10.0, -5.0, 7.0, 2.0])
    s_p = np.array([[30.0, -20.0], [30.0, -20.0]])
    gammas, variance, visual_variance = np.array([1.0, 0.3]), 0.5, 0.1
    system = System([Constant("shoulder", unit="deg"), Constant("elbow", unit="deg"), LinearDecoder(A, b, seen),
                     Brain()],
                    [("shoulder.y", "brain.q_shoulder"), ("elbow.y", "brain.q_elbow"), ("brain.mu", "decoder.mu"),
                     ("decoder.visual_drive", "brain.visual_drive"), ("decoder.visual_error", "brain.visual_error"),
                     ("decoder.visual_stiffness", "brain.visual_stiffness")])
    result = simulate(system, stop_time=10.0, step_size=0.05, batch_size=2,
                      parameters={"shoulder.value": s_p[:, 0], "elbow.value": s_p[:, 1], "brain.mu0": [25.0, -10.0],
                                  "brain.gamma0": gammas, "brain.proprioceptive_variance": variance,
                                  "decoder.visual_variance": visual_variance},
                      record=["brain.mu", "brain.gamma", "brain.free_energy", "decoder.prediction"])
    np.testing.assert_array_equal(result.values["brain.gamma"][-1], gammas)  # held: no events, floor gamma0
    # the decoder, before the brain in the order, saw mu0 already at initialization
    mu0 = np.array([25.0, -10.0])
    np.testing.assert_allclose(result.values["decoder.prediction"][0], np.tile(A @ mu0 + b, (2, 1)), rtol=1e-15)
    # F: NaN before any step, then evaluated at the belief each step starts from
    initial = ((s_p - mu0) ** 2).sum(axis=1) / (2 * variance) + gammas * (
        (seen - A @ mu0 - b) ** 2).sum() / (2 * visual_variance)
    assert np.isnan(result.values["brain.free_energy"][0]).all()
    np.testing.assert_allclose(result.values["brain.free_energy"][1], initial, rtol=1e-13)
    for trial, gamma in enumerate(gammas):
        precision = np.eye(2) / variance + gamma * A.T @ A / visual_variance
        target = np.linalg.solve(precision, s_p[trial] / variance + gamma * A.T @ (seen - b) / visual_variance)
        np.testing.assert_allclose(result.values["brain.mu"][-1, trial], target, rtol=0, atol=1e-10)
        minimum = (((s_p[trial] - target) ** 2).sum() / (2 * variance)
                   + gamma * ((seen - A @ target - b) ** 2).sum() / (2 * visual_variance))
        assert result.values["brain.free_energy"][-1, trial] == pytest.approx(minimum, rel=1e-10)
        assert np.all(np.diff(result.values["brain.free_energy"][1:, trial]) <= 1e-12)  # F descends


# -- batches ---------------------------------------------------------------------------------------

def scripted_inputs(trial, steps, rng):
    """Per-trial inputs: drifting s_p, a random drive, events every 1 s with a trial-specific delay."""
    delay = (0.03, 0.3, 0.7)[trial]
    times = (np.arange(steps) + 1) * H
    visual = np.where(times >= 1.0, np.floor(times + 1e-9), -np.inf)
    tactile = np.where(times >= 1.0 + delay, np.floor(times - delay + 1e-9) + delay, -np.inf)
    return {"q_shoulder": 140 + np.cumsum(rng.normal(0, 0.1, steps)), "q_elbow": -90 + rng.normal(0, 0.5, steps),
            "visual_drive": rng.normal(0, 5, (steps, 2)), "visual_error": rng.uniform(0, 3, steps),
            "visual_stiffness": rng.uniform(0, 20, steps), "visual_time": visual, "tactile_time": tactile}


def test_a_batch_gives_the_numbers_of_single_runs():
    steps, rng = 250, np.random.default_rng(7)
    scripts = [scripted_inputs(trial, steps, rng) for trial in range(3)]
    parameters = {"proprioceptive_variance": [1.0, 0.7, 2.0], "gamma0": [0.01, 0.05, 0.3],
                  "mu0": [[140.0, -90.0], [141.0, -92.0], [139.0, -89.0]], "sync_sd": [0.2, 0.1, 0.3]}
    outputs = ("mu", "u_shoulder", "u_elbow", "action_rate", "gamma", "free_energy")

    def run(trials):
        brain = started(len(trials), inputs={k: np.array([scripts[i][k][0] for i in trials]) for k in scripts[0]},
                        **{k: np.array(v)[trials] for k, v in parameters.items()})
        history = []
        for n in range(steps):
            advance(brain, n * H, **{k: np.array([scripts[i][k][n] for i in trials]) for k in scripts[0]})
            history.append({k: brain.get(k).copy() for k in outputs})
        return history

    batch = run([0, 1, 2])
    final = batch[-1]["gamma"]
    assert final[0] > 0.5 and (final[1], final[2]) == (0.05, 0.3)  # sync rises, async sits at its floor
    for trial in range(3):
        single = run([trial])
        for n in range(steps):
            for k in outputs:
                np.testing.assert_allclose(batch[n][k][trial], single[n][k][0], rtol=1e-12, atol=1e-12)


# -- the extension: causal inference over space ---------------------------------------------------

def test_spatial_likelihood_by_hand_and_off_by_default():
    from rhi.components.brain.touch_timing import spatial_likelihood

    seen = np.array([[-0.45, 0.5], [0.0, 0.0], [np.nan, np.nan]])
    felt = np.array([[-0.30, 0.5], [0.3, 0.4], [np.nan, 1.0]])
    factor = spatial_likelihood(seen, felt, np.array([0.2, 0.25, np.inf]))
    assert factor[0] == pytest.approx(math.exp(-0.15 ** 2 / (2 * 0.2 ** 2)), rel=1e-14)
    assert factor[1] == pytest.approx(math.exp(-(0.3 ** 2 + 0.4 ** 2) / (2 * 0.25 ** 2)), rel=1e-14)
    assert factor[2] == 1.0  # inf: the paper's model; the positions are not read (NaN is fine)
    assert Brain().variables["spatial_sd"].start == np.inf


def test_gamma_with_space_is_bayes_with_the_spatial_factor():
    """A synchronous pair with the hands 15 cm apart: p1 = N(delay) * exp(-d^2 / (2 sigma_s^2)); with
    sigma_s = inf the same brain gives the paper's update."""
    inputs = {"seen_hand": [[-0.45, 0.5]], "hand_x": -0.30, "hand_y": 0.5}
    spatial, paper = started(gamma0=0.01, spatial_sd=0.1, inputs=inputs), started(gamma0=0.01, inputs=inputs)
    for brain in (spatial, paper):
        advance(brain, 1.0, visual_time=1.0, tactile_time=1.02)
    p1 = normal_pdf(-0.02)
    factor = math.exp(-0.15 ** 2 / (2 * 0.1 ** 2))
    expected = p1 * factor * 0.01 / (p1 * factor * 0.01 + 0.5 * 0.99)
    assert spatial.get("gamma")[0] == pytest.approx(max(expected, 0.01), rel=1e-13)
    assert paper.get("gamma")[0] == pytest.approx(p1 * 0.01 / (p1 * 0.01 + 0.5 * 0.99), rel=1e-13)
    assert spatial.get("gamma")[0] < paper.get("gamma")[0]


def test_spatial_extension_needs_the_hands_connected():
    unconnected = {"seen_hand": np.full((2, 2), np.nan), "hand_x": np.full(2, np.nan), "hand_y": np.full(2, np.nan)}
    brain = started(batch=2, spatial_sd=[np.inf, 0.2], inputs=unconnected)  # the hands' start values
    assert brain.do_step(0.0, H) == Status.ERROR
    assert brain.last_reason.startswith("seen_hand is not finite (nan) in trial 1 (brain.spatial_sd is finite")
    with pytest.raises(ComponentError, match=r"brain\.spatial_sd must be positive \(inf: the paper's model\), got 0"):
        started(spatial_sd=0.0)
