"""What a trial measures (docs/design.md, Measures), by hand on constructed recordings: measures() and the sweep's
per-trial outcome (rhi.master.tasks.illusion.runner.trial_outcome).

The truth is written here: hand positions by inverse kinematics, the Jacobian by central differences of the
forward kinematics. Drift = x of the perceived hand (forward kinematics of mu) minus x of the real hand, the hand
the body SENSES (its joint angles), not the resting hand; negative is to the left.
"""
from types import SimpleNamespace

import numpy as np
import pytest

from rhi.components.body.kinematics import REST_HAND, REST_POSE, SHOULDER, forward, inverse
from rhi.components.vision.component import Decoder
from rhi.master import config as configuration
from rhi.master.tasks.illusion import measures, run_batch, trial_seed
from rhi.master.tasks.illusion import runner
from rhi.master.runtime.pool import JOB_THREADS
from tests.test_batching import three_trials, tiny_config, tiny_model

STEPS = 3  # rows per constructed recording: steps + 1 = 4


def pose_at(x, y):
    return np.array(inverse(x, y), dtype=float)


def recording(mu, q, action_rate=None, **extra):
    """A Result-like recording: ``mu`` and ``q`` (rows, B, 2) deg; the other recorded paths filled with marks."""
    mu, q = np.asarray(mu, float), np.asarray(q, float)
    rows, batch = mu.shape[:2]
    mark = lambda value: np.full((rows, batch), float(value))  # noqa: E731
    values = {"brain.mu": mu, "body.q_shoulder": q[..., 0], "body.q_elbow": q[..., 1],
              "brain.action_rate": np.zeros((rows, batch, 2)) if action_rate is None else np.asarray(action_rate),
              "body.force_x": mark(1.5), "body.force_y": mark(-2.5), "brain.gamma": mark(0.25),
              "brain.u_shoulder": mark(0.75), "brain.u_elbow": mark(-0.5), "stimulus.visual_time": mark(4.0),
              "stimulus.tactile_time": mark(4.05), "decoder.visual_error": mark(12.0), "brain.free_energy": mark(3.0),
              "stimulus.ball": np.broadcast_to([-0.45, 0.6], (rows, batch, 2)).copy(),
              "body.hand_x": mark(-0.3), "body.hand_y": mark(0.5)}
    values.update(extra)
    return SimpleNamespace(values=values, times=np.arange(rows) * 0.02)


def constant(pose, rows=STEPS + 1):
    """One trial holding ``pose`` (2,) for every row: (rows, 1, 2)."""
    return np.broadcast_to(np.asarray(pose, float), (rows, 1, 2)).copy()


def test_drift_is_the_perceived_hand_minus_the_sensed_hand_along_x_in_cm_negative_to_the_left():
    """Real arm at rest; beliefs whose hands lie 2 cm left, 3 cm right, and 4 cm forward (same x) of it."""
    rest = np.array(REST_POSE)
    beliefs = [pose_at(REST_HAND[0] - 0.02, REST_HAND[1]), pose_at(REST_HAND[0] + 0.03, REST_HAND[1]),
               pose_at(REST_HAND[0], REST_HAND[1] + 0.04), rest]
    mu = np.stack([constant(b)[:, 0] for b in beliefs], axis=1)
    drift = measures(recording(mu, np.broadcast_to(rest, mu.shape)))["drift_cm"]
    assert drift.shape == (STEPS + 1, 4)
    np.testing.assert_allclose(drift, np.broadcast_to([-2.0, 3.0, 0.0, 0.0], drift.shape), rtol=0, atol=1e-9)


def test_the_real_hand_is_the_sensed_hand_not_the_resting_hand():
    """The real arm is away from rest (its hand 5 cm right and 2 cm forward of the resting hand): a belief equal to
    the sensed angles has no drift, and a belief at the rest pose drifts 5 cm LEFT of the sensed hand."""
    sensed = pose_at(REST_HAND[0] + 0.05, REST_HAND[1] + 0.02)
    mu = np.concatenate([constant(sensed), constant(REST_POSE), constant(pose_at(REST_HAND[0] + 0.04, 0.6))], axis=1)
    q = np.broadcast_to(sensed, mu.shape)
    drift = measures(recording(mu, q))["drift_cm"]
    np.testing.assert_allclose(drift[-1], [0.0, -5.0, -1.0], rtol=0, atol=1e-9)


def test_drift_follows_the_sensed_hand_row_by_row():
    """The sensed arm moves from row to row (0, 1, 2, 3 cm right), the belief stays at rest: drift 0, -1, -2, -3 cm."""
    q = np.stack([pose_at(REST_HAND[0] + 0.01 * k, REST_HAND[1]) for k in range(STEPS + 1)])[:, None]
    drift = measures(recording(constant(REST_POSE), q))["drift_cm"][:, 0]
    np.testing.assert_allclose(drift, [0.0, -1.0, -2.0, -3.0], rtol=0, atol=1e-9)


def test_action_acceleration_is_the_action_rate_through_the_arms_jacobian():
    """x-acceleration of the hand (m/s^2) = dx/dq . a_dot, the Jacobian by central differences of the forward kinematics at the
    SENSED angles (m/deg). A pure shoulder rate at the rest pose swings the hand about the shoulder, 0.5 m behind it:
    dx = -0.5 m x pi/180 per deg, to the left."""
    sensed = [np.array(REST_POSE), pose_at(-0.40, 0.45)]
    rates = np.array([[1.0, 0.0], [0.3, -0.7]])
    q = np.stack([constant(p)[:, 0] for p in sensed], axis=1)
    a_dot = np.broadcast_to(rates, q.shape)
    out = measures(recording(constant(REST_POSE, STEPS + 1).repeat(2, axis=1), q, a_dot))
    step = 1e-5  # deg
    for trial, (pose, rate) in enumerate(zip(sensed, rates)):
        gradient = np.array([(forward(*(pose + d))[0] - forward(*(pose - d))[0]) / (2 * step)
                             for d in np.eye(2) * step])  # m/deg
        np.testing.assert_allclose(out["action_accel_x_m_s2"][:, trial], gradient @ rate, rtol=1e-7)
    assert out["action_accel_x_m_s2"][0, 0] == pytest.approx(-(REST_HAND[1] - SHOULDER[1]) * np.pi / 180, rel=1e-12)


def test_every_column_comes_from_its_recorded_variable():
    rest = np.array(REST_POSE)
    mu = constant(rest + [0.5, -0.25])
    out = measures(recording(mu, constant(rest), np.broadcast_to([0.125, -0.375], mu.shape)))
    expected = {"force_x_n": 1.5, "force_y_n": -2.5, "gamma": 0.25, "mu_shoulder_deg": rest[0] + 0.5,
                "mu_elbow_deg": rest[1] - 0.25, "s_p_shoulder_deg": rest[0], "s_p_elbow_deg": rest[1],
                "action_shoulder_deg_s": 0.75, "action_elbow_deg_s": -0.5, "action_rate_shoulder_deg_s2": 0.125,
                "action_rate_elbow_deg_s2": -0.375, "visual_time_s": 4.0, "tactile_time_s": 4.05, "visual_error": 12.0,
                "free_energy": 3.0, "ball_x_m": -0.45, "ball_y_m": 0.6}
    for key, value in expected.items():
        assert out[key].shape == (STEPS + 1, 1), key
        np.testing.assert_allclose(out[key], value, rtol=0, atol=1e-12, err_msg=key)


def test_trial_outcome_is_the_last_row_of_the_trials_measures(monkeypatch):
    """The sweep's per-trial outcome: drift, the horizontal force and gamma at the end of the trial, and its seed
    (the protocol's hash of master seed, condition, stimulation and index)."""
    config = configuration.load(quick=True)
    sensed = pose_at(REST_HAND[0] + 0.01, REST_HAND[1])
    mu = np.concatenate([constant(sensed)[:-1], constant(pose_at(REST_HAND[0] - 0.025, REST_HAND[1]), 1)])
    made = recording(mu, constant(sensed), **{"body.force_x": np.array([[0.0], [0.1], [0.2], [-0.7]]),
                                              "brain.gamma": np.array([[0.01], [0.2], [0.5], [0.9]])})
    calls = []

    def run_batch(decoder, trials, given, body=None):
        calls.append((decoder, trials, given))
        assert body is None  # the configuration's body: the default pymunk arm
        return made

    monkeypatch.setattr(runner, "run_batch", run_batch)
    monkeypatch.setattr("rhi.master.decoders.cache.decoder_component",
                        lambda kind, path, given, threads=None: ("decoder", path, threads))
    outcome = runner.trial_outcome(config, "vae", "left", "async", 3, checkpoint="model.pt")
    (decoder, trials, given), = calls
    # on one torch thread, as the experiment's batches
    assert decoder == ("decoder", "model.pt", JOB_THREADS) and given is config and len(trials) == 1
    trial = trials[0]
    assert (trial.decoder, trial.condition, trial.stimulation, trial.index) == ("vae", "left", "async", 3)
    assert (trial.offset_x, trial.delay_min, trial.delay_max) == (-0.15, 0.0, 1.0)
    assert outcome["seed"] == trial.seed == trial_seed(config["experiment"]["seed"], "left", "async", 3)
    assert outcome["drift_cm"] == pytest.approx(-3.5, abs=1e-9)  # 2.5 cm left of a hand sensed 1 cm right of rest
    assert (outcome["force_n"], outcome["gamma_final"], outcome["force_y_n"]) == (-0.7, 0.9, -2.5)
    assert all(isinstance(value, (int, float)) for value in outcome.values())


def test_a_run_starts_with_the_belief_on_the_sensed_arm_at_rest():
    """Before anything happened there is no illusion: mu(0) is the real arm's sensed pose, the rest pose docs/design.md
    fixes (the decoders are trained around it), so every trial's drift starts at exactly 0."""
    config = tiny_config(steps=2)
    result = run_batch(Decoder(tiny_model(), threads=1), three_trials(config), config)
    first = {path: values[0] for path, values in result.values.items()}
    np.testing.assert_array_equal(first["brain.mu"], np.broadcast_to(REST_POSE, (3, 2)))
    np.testing.assert_array_equal(first["body.q_shoulder"], np.full(3, REST_POSE[0]))
    np.testing.assert_array_equal(first["body.q_elbow"], np.full(3, REST_POSE[1]))
    np.testing.assert_array_equal(measures(result)["drift_cm"][0], np.zeros(3))
