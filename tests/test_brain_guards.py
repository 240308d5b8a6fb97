"""The brains' guards and bad input (stability, non-finite values, parameter ranges, event bookkeeping), every
brain class through the same cases, and the two action laws (the paper's integrator, the leaky law) by hand."""
import numpy as np
import pytest

from rhi.components.brain import Brain
from rhi.components.brain.action_law import action_update, euler_step
from rhi.components.brain.touch_timing import observe_events
from rhi.components.brain.integrator import belief_rate
from rhi.components.component import ComponentError, Status
from rhi.master import SimulationError, System, simulate
from tests.linear_decoder import LinearDecoder
from tests.toys import Constant

from tests.brain_steps import BRAINS, H, advance, outputs, started

every_brain = pytest.mark.parametrize("kind", BRAINS, ids=lambda kind: kind.__name__)


# -- guards and bad input ----------------------------------------------------------------------------

def test_stability_guard_fails_the_step_and_keeps_the_state():
    brain = started(gamma0=1.0, mu0=[1.0, 2.0], inputs={"visual_stiffness": 120.0})  # 0.02 * (1 + 120) = 2.42
    assert brain.do_step(0.0, H) == Status.ERROR
    assert brain.last_reason.startswith("step too large for stable explicit Euler in trial 0: dt * (1/Sigma_p + "
                                        "gamma * visual_stiffness) = 2.42 >= 2")
    np.testing.assert_array_equal(brain.get("mu"), [[1.0, 2.0]])
    advance(brain, 0.0, visual_stiffness=90.0)  # 1.82 < 2 passes
    quiet = started(gamma0=0.01, inputs={"visual_stiffness": 120.0})  # gamma scales the visual stiffness
    advance(quiet, 0.0)


@every_brain
def test_every_brain_fails_an_unstable_belief_step_and_keeps_its_state(kind):
    """A goal's stiffness enters every brain's stability number: 0.02 * (1/Sigma_p + ... + 120) > 2."""
    brain = started(kind=kind, mu0=[1.0, 2.0], inputs={"goal_stiffness": 120.0})
    before = outputs(brain)
    assert brain.do_step(0.0, H) == Status.ERROR
    assert brain.last_reason.startswith("step too large for stable explicit Euler in trial 0: dt * (1/Sigma_p + ")
    assert " + goal_stiffness) = " in brain.last_reason and ">= 2 (dt = 0.02 s, Sigma_p = 1, gamma = " \
        in brain.last_reason
    assert all(np.array_equal(value, before[name], equal_nan=True) for name, value in outputs(brain).items())
    advance(brain, 0.0, goal_stiffness=0.0)


def test_stability_guard_through_the_master():
    A, seen = np.array([[10.0, 0.0], [0.0, 1.0]]), np.zeros(2)
    system = System([Constant("shoulder", unit="deg"), Constant("elbow", unit="deg"),
                     LinearDecoder(A, np.zeros(2), seen), Brain()],
                    [("shoulder.y", "brain.q_shoulder"), ("elbow.y", "brain.q_elbow"), ("brain.mu", "decoder.mu"),
                     ("decoder.visual_drive", "brain.visual_drive"),
                     ("decoder.visual_stiffness", "brain.visual_stiffness")])
    with pytest.raises(SimulationError, match=r"brain failed the step at t = 0 s \(error\): step too large .* "
                                              r"= 2\.02 >= 2 .*visual_stiffness = 100 1/s"):
        simulate(system, 1.0, H, parameters={"brain.gamma0": 1.0})


@every_brain
@pytest.mark.parametrize("name, value", [("q_shoulder", np.nan), ("q_elbow", np.inf), ("visual_stiffness", np.nan),
                                         ("goal_error", np.nan), ("visual_time", np.nan), ("tactile_time", np.inf)])
def test_non_finite_input_names_the_variable_and_trial(kind, name, value):
    if name not in kind().variables:
        pytest.skip(f"{kind.__name__} reads no {name}")  # the ownership brain has no pixel term
    brain = started(batch=3, kind=kind)
    before = outputs(brain)
    values = np.zeros(3)
    values[1] = value
    brain.set(name, values)
    assert brain.do_step(0.0, H) == Status.ERROR
    assert brain.last_reason == f"{name} is not finite ({value}) in trial 1"
    assert all(np.array_equal(value, before[name], equal_nan=True) for name, value in outputs(brain).items())


def test_non_finite_drive_and_belief_are_named():
    brain = started(batch=2)
    brain.set("visual_drive", [[0.0, 0.0], [0.0, np.nan]])
    assert brain.do_step(0.0, H) == Status.ERROR and brain.last_reason == "visual_drive is not finite (nan) in trial 1"
    brain = started(batch=2)
    brain.set("visual_error", [0.0, np.nan])
    assert brain.do_step(0.0, H) == Status.ERROR and brain.last_reason == "visual_error is not finite (nan) in trial 1"
    big = started(gamma0=1.0, mu0=[1.79e308, 0.0], inputs={"q_shoulder": 1.79e308, "visual_drive": [[1e308, 0.0]]})
    assert big.do_step(0.0, H) == Status.ERROR and big.last_reason == "mu is not finite (inf) in trial 0"


@every_brain
@pytest.mark.parametrize("name, value, message", [
    ("proprioceptive_variance", np.inf, r"brain\.proprioceptive_variance must be positive and finite, got inf"),
    ("action_limit", np.inf, r"brain\.action_limit must be positive and finite, got inf"),
    ("action_time_constant", 0.0, r"brain\.action_time_constant must be positive \(inf: the paper's law\), got 0\.0"),
    ("action_time_constant", np.nan, r"brain\.action_time_constant must be positive \(inf: the paper's law\), got nan"),
    ("mu0", [np.nan, 0.0], r"brain\.mu0 must be finite, got \[\[nan, 0\.0\]\]")])
def test_every_brain_names_a_bad_shared_parameter_at_initialization(kind, name, value, message):
    with pytest.raises(ComponentError, match=message):
        started(kind=kind, **{name: value})


@pytest.mark.parametrize("name, value, message", [
    ("proprioceptive_variance", 0.0, r"brain\.proprioceptive_variance must be positive and finite, got 0\.0"),
    ("sync_sd", 0.0, r"brain\.sync_sd must be positive and finite, got 0\.0"),
    ("async_density", np.inf, r"brain\.async_density must be positive and finite, got inf"),
    ("action_limit", 0.0, r"brain\.action_limit must be positive and finite, got 0\.0")])
def test_bad_parameter_is_named_at_initialization(name, value, message):
    with pytest.raises(ComponentError, match=message):
        started(**{name: value})


def test_parameter_range_and_unconnected_proprioception_are_named():
    with pytest.raises(ComponentError, match=r"brain\.gamma0 = 1\.5 is outside its range \[0\.0, 1\.0\]"):
        started(gamma0=1.5)
    # s_p starts as NaN; sources later in the order feed it from the first step on
    late = System([Brain(), Constant("shoulder", unit="deg"), Constant("elbow", unit="deg")],
                  [("shoulder.y", "brain.q_shoulder"), ("elbow.y", "brain.q_elbow")])
    energy = simulate(late, 2 * H, H, parameters={"shoulder.value": 3.0, "elbow.value": 4.0},
                      record=["brain.free_energy"]).values["brain.free_energy"][:, 0]
    assert np.isnan(energy[0]) and energy[1] == pytest.approx((3.0 ** 2 + 4.0 ** 2) / 2, rel=1e-15)
    # never fed: the first step names it
    with pytest.raises(SimulationError, match=r"brain failed the step at t = 0 s \(error\): q_elbow is not "
                                              r"finite \(nan\) in trial 0"):
        simulate(System([Brain(), Constant("shoulder", unit="deg")], [("shoulder.y", "brain.q_shoulder")]), 0.1, H)


def test_belief_and_gamma_are_readable_in_initialization_mode():
    """The decoder, before the brain in the order, reads mu0 while the brain is in initialization mode."""
    brain = Brain()
    brain.instantiate(2)
    brain.set("mu0", [[140.0, -90.0], [150.0, -80.0]])
    brain.set("gamma0", 0.2)
    brain.setup_experiment(0.0)
    brain.enter_initialization_mode()
    np.testing.assert_array_equal(brain.get("mu"), [[140.0, -90.0], [150.0, -80.0]])
    np.testing.assert_array_equal(brain.get("gamma"), [0.2, 0.2])
    assert np.isnan(brain.get("free_energy")).all() and not brain.get("u_shoulder").any()


def test_event_bookkeeping_fires_bayes_once_per_new_pair():
    """A pair is a new visual and a new tactile event since the last Bayes update, in either order and on
    different steps; an event seen again (same time) is not new, and none fires before any event."""
    state = (np.full(2, -np.inf), np.full(2, -np.inf), np.zeros(2, bool), np.zeros(2, bool))
    times = [([-np.inf, -np.inf], [-np.inf, -np.inf]),  # nothing yet
             ([2.0, -np.inf], [-np.inf, 0.5]),          # trial 0: visual; trial 1: tactile first
             ([2.0, -np.inf], [-np.inf, 0.5]),          # the same times again: nothing new
             ([2.0, 2.0], [2.05, 0.5]),                 # both trials complete their pair
             ([2.0, 2.0], [2.05, 0.5]),                 # seen: no second Bayes update
             ([4.0, 4.0], [2.05, 4.3])]                 # trial 0: a visual alone; trial 1: both at once
    fired = []
    for visual, tactile in times:
        pair, *state = observe_events(*state, np.array(visual), np.array(tactile))
        fired.append(pair.tolist())
    assert fired == [[False, False], [False, False], [False, False], [True, True], [False, False], [False, True]]
    assert state[2].tolist() == [True, False] and not state[3].any()  # trial 0 waits for a touch


def test_euler_step_updates_the_belief_then_the_action_from_it_and_clips():
    mu, s_p, drive = np.array([[10.0, 20.0]]), np.array([[10.5, 19.0]]), np.array([[3.0, -4.0]])
    one = np.ones(1)
    mu_dot = belief_rate(s_p, mu, 0.5 * one, drive, 2.0 * one)
    new_mu, a_dot, action = euler_step(mu, mu_dot, np.array([[-0.995, -0.2]]), s_p, 2.0 * one, one, np.inf * one, 0.1)
    np.testing.assert_allclose(new_mu, mu + 0.1 * ((s_p - mu) / 2.0 + 0.5 * drive), rtol=1e-15)
    np.testing.assert_allclose(a_dot, -(s_p - new_mu) / 2.0, rtol=1e-15)
    np.testing.assert_allclose(action, [[-1.0, -0.2 + 0.1 * a_dot[0, 1]]], rtol=1e-15)  # shoulder clipped at -1
    # the leaky law in the same step: a + h (a_dot - a/tau), then the clip
    _, _, leaky = euler_step(mu, mu_dot, np.array([[-0.995, -0.2]]), s_p, 2.0 * one, one, 0.5 * one, 0.1)
    np.testing.assert_allclose(leaky, [[-0.995 + 0.1 * (a_dot[0, 0] + 0.995 / 0.5),
                                        -0.2 + 0.1 * (a_dot[0, 1] + 0.2 / 0.5)]], rtol=1e-15)


# -- the action laws ------------------------------------------------------------------------------

def test_paper_law_is_the_released_agent_s_integrator_bit_for_bit():
    """tau = inf: a <- clip(a + h a_dot), the same bits as the formula written out, also for -0.0 and at the clip."""
    rng = np.random.default_rng(3)
    action, a_dot = rng.uniform(-1, 1, (50, 2)), rng.normal(0, 20, (50, 2))
    action[0], a_dot[1] = [-0.0, 0.0], [-0.0, 0.0]
    limit = np.full(50, 0.9)
    expected = np.clip(action + 0.02 * a_dot, -0.9, 0.9)
    got = action_update(action, a_dot, np.full(50, np.inf), limit, 0.02)
    assert got.tobytes() == expected.tobytes()


def test_leaky_law_by_hand_and_its_fixed_point():
    """a_{n+1} = a_n + h (a_dot - a_n / tau) by hand over steps; a constant gap settles at a = tau * a_dot
    = -tau (s_p - mu) / Sigma_p, geometrically at the rate (1 - h/tau) per step, below the clip."""
    tau, variance, h = 0.1, 2.0, 0.02
    s_p, mu = np.array([147.0, -91.0]), np.array([147.3, -91.1])  # gamma0 = 0: mu relaxes, so compute a_dot per step
    brain = started(gamma0=0.0, proprioceptive_variance=variance, mu0=mu, action_time_constant=tau,
                    inputs={"q_shoulder": s_p[0], "q_elbow": s_p[1]})
    a, belief = np.zeros(2), mu.copy()
    for n in range(40):
        advance(brain, n * h)
        belief = belief + h * (s_p - belief) / variance
        a_dot = -(s_p - belief) / variance
        a = a + h * (a_dot - a / tau)
        np.testing.assert_allclose(brain.get("action_rate")[0], a_dot, rtol=1e-13)
        np.testing.assert_allclose([brain.get("u_shoulder")[0], brain.get("u_elbow")[0]], a, rtol=1e-12)
    # with the gap held constant (a steady a_dot), the action converges to tau * a_dot
    steady = np.array([[0.6, -0.3]])
    action = np.zeros((1, 2))
    for n in range(400):
        action = action_update(action, steady, np.array([tau]), np.array([1.0]), h)
    np.testing.assert_allclose(action, tau * steady, rtol=1e-12)
    one_step = action_update(np.zeros((1, 2)), steady, np.array([tau]), np.array([1.0]), h)
    np.testing.assert_allclose(one_step, h * steady, rtol=1e-15)  # from rest, the first step is the paper's
    # the clip still bounds it: tau * a_dot = 3 deg/s against a limit of 1
    big = action_update(np.zeros((1, 2)), np.array([[30.0, -30.0]]), np.array([tau]), np.array([1.0]), 1.0 * tau)
    assert big.tolist() == [[1.0, -1.0]]


def test_paper_and_leaky_laws_in_one_batch():
    s_p, mu = [0.0, 0.0], [20.0, -10.0]  # the gap relaxes at 1/Sigma_p = 0.25/s; its integral is the gap
    brain = started(batch=2, gamma0=0.0, mu0=mu, proprioceptive_variance=4.0, action_time_constant=[np.inf, 0.05],
                    inputs={"q_shoulder": s_p[0], "q_elbow": s_p[1]})
    for n in range(200):
        advance(brain, n * H)
    paper, leaky = np.stack([brain.get("u_shoulder"), brain.get("u_elbow")], axis=1)
    assert paper.tolist() == [1.0, -1.0]  # integrated to the clip
    a_dot = brain.get("action_rate")[1]
    np.testing.assert_allclose(leaky, 0.05 * a_dot, rtol=0.02)  # tracks tau * a_dot (lag ~ tau/Sigma_p = 1.25 %)


@every_brain
def test_leaky_action_step_guard(kind):
    brain = started(kind=kind, batch=2, action_time_constant=[0.1, 0.005])  # 0.02 / 0.005 = 4
    before = outputs(brain)
    assert brain.do_step(0.0, H) == Status.ERROR
    assert brain.last_reason == ("step too large for the leaky action in trial 1: dt / action_time_constant = 4 >= 2 "
                                 "(dt = 0.02 s, action_time_constant = 0.005 s); use a smaller step or a longer "
                                 "action_time_constant")
    assert all(np.array_equal(value, before[name], equal_nan=True) for name, value in outputs(brain).items())
    brain = started(kind=kind, action_time_constant=0.009)  # 0.02 / 0.009 = 2.22
    assert brain.do_step(0.0, H) == Status.ERROR
    assert brain.last_reason.startswith("step too large for the leaky action in trial 0: dt / action_time_constant "
                                        "= 2.222 >= 2")
    advance(started(kind=kind, action_time_constant=0.011), 0.0)


@every_brain
def test_a_failed_step_changes_nothing_a_retry_would_see(kind):
    """A step that fails at a new pair of events, retried, gives the bits of a brain that never failed: the
    events, gamma and (the causal model's) each participant's timing noise move on only with a passed step."""
    events = [{"visual_time": 0.02, "tactile_time": 0.01}, {}, {"visual_time": 0.06, "tactile_time": 0.08}, {}]
    failed, clean = started(kind=kind, batch=2), started(kind=kind, batch=2)
    failed.set("goal_stiffness", 120.0)
    failed.set("visual_time", 0.02)
    failed.set("tactile_time", 0.01)
    assert failed.do_step(0.0, H) == Status.ERROR and failed.last_reason.startswith("step too large")
    failed.set("goal_stiffness", 0.0)
    for n, inputs in enumerate(events):
        advance(failed, n * H, **inputs)
        advance(clean, n * H, **inputs)
        after, expected = outputs(failed), outputs(clean)
        assert all(np.array_equal(after[name], expected[name], equal_nan=True) for name in expected)
    held = "gamma0" in clean.variables and np.array_equal(clean.get("gamma"), clean.get("gamma0"))  # a fixed gamma
    assert held or not np.array_equal(outputs(clean)["gamma"], started(kind=kind, batch=2).get("gamma"))  # pairs counted
