"""Kinematics, the pymunk arm plant (held and free) and the rubber arm, against hand computation and statics."""
import math

import numpy as np
import pytest

from rhi.components.body.kinematics import FOREARM, REST_HAND, REST_POSE, SHOULDER, UPPER_ARM, forward, inverse, jacobian
from rhi.components.body.plant import ArmPlant
from rhi.components.body.rubber_arm import RubberArm
from rhi.components.component import ComponentError, Status
from rhi.master.config import defaults

# Poses whose hand positions are sums of the segment lengths, worked out by hand.
HAND_COMPUTED = [
    ((90.0, 0.0), (-0.20, 0.3595 + 0.3694)),      # straight forward
    ((0.0, 0.0), (-0.20 + 0.3595 + 0.3694, 0.0)),  # straight to the right
    ((180.0, -90.0), (-0.20 - 0.3595, 0.3694)),    # upper arm left, forearm forward
    ((90.0, -90.0), (-0.20 + 0.3694, 0.3595)),     # upper arm forward, forearm right
]


@pytest.mark.parametrize("pose, hand", HAND_COMPUTED)
def test_forward_and_inverse_match_hand_computed_values(pose, hand):
    assert np.allclose(forward(*pose), hand, atol=1e-9, rtol=0)
    if pose[1] < 0:  # the elbow-outward branch is the one inverse returns
        assert np.allclose(inverse(*hand), pose, atol=1e-9, rtol=0)


def test_rest_pose_and_round_trip_on_a_grid():
    assert REST_POSE == pytest.approx((147.7, -91.2), abs=0.05)
    assert np.allclose(forward(*REST_POSE), REST_HAND, atol=1e-12)
    radius, angle = np.meshgrid(np.linspace(0.02, 0.72, 15), np.radians(np.linspace(5, 175, 18)))
    x, y = SHOULDER[0] + radius * np.cos(angle), SHOULDER[1] + radius * np.sin(angle)
    shoulder, elbow = inverse(x, y)
    assert shoulder.shape == x.shape and np.all(elbow <= 0)
    assert np.allclose(forward(shoulder, elbow), (x, y), atol=1e-9, rtol=0)


def test_jacobian_matches_hand_value_and_finite_differences():
    per_degree = math.pi / 180
    assert np.allclose(jacobian(180.0, -90.0), [[-FOREARM * per_degree, -FOREARM * per_degree],
                                                [-UPPER_ARM * per_degree, 0.0]], atol=1e-15)
    poses = np.array([REST_POSE, (120.0, -40.0), (170.0, -130.0)])
    step = 1e-5
    for pose, analytic in zip(poses, jacobian(poses[:, 0], poses[:, 1])):
        for column, delta in enumerate(np.eye(2) * step):
            numeric = (np.array(forward(*(pose + delta))) - np.array(forward(*(pose - delta)))) / (2 * step)
            assert np.allclose(analytic[:, column], numeric, rtol=1e-8, atol=1e-12)


@pytest.mark.parametrize("x, y", [(0.7, 0.7), (SHOULDER[0], SHOULDER[1] + 0.001), (np.nan, 0.5)])
def test_pose_out_of_reach_is_one_clear_error(x, y):
    with pytest.raises(ComponentError, match=r"hand position \(x, y\) = .* out of reach"):
        inverse(x, y)


def start(component, batch_size, **parameters):
    component.instantiate(batch_size)
    for name, value in parameters.items():
        component.set(name, value)
    component.enter_initialization_mode()
    component.exit_initialization_mode()
    return component


def test_rubber_hands_land_15_cm_left_and_right_of_the_real_hand():
    offsets = list(defaults()["conditions"].values())  # left, center, right
    arm = start(RubberArm(), 3, offset_x=offsets)
    hand, pose = arm.get("hand"), arm.get("pose")
    assert np.allclose(hand[:, 0] - REST_HAND[0], [-0.15, 0.0, 0.15], atol=1e-12)
    assert np.allclose(forward(pose[:, 0], pose[:, 1]), (hand[:, 0], hand[:, 1]), atol=1e-9, rtol=0)
    assert np.allclose(pose[1], REST_POSE, atol=1e-9)
    assert arm.do_step(0.0, 0.02) == Status.OK and np.array_equal(arm.get("hand"), hand)


def test_rubber_arm_out_of_reach_names_the_offset():
    with pytest.raises(ComponentError, match="offset_x/offset_y"):
        start(RubberArm(), 1, offset_x=2.0)


def run_plant(commands, seconds, held, step=0.02, **parameters):
    """Run the plant with constant commands (B, 2) deg/s; returns {output: (steps + 1, B)}."""
    commands = np.asarray(commands, dtype=float)
    plant = start(ArmPlant(), len(commands), held=held, **parameters)
    plant.set("u_shoulder", commands[:, 0])
    plant.set("u_elbow", commands[:, 1])
    names = ("q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y")
    rows = [{n: plant.get(n) for n in names}]
    for tick in range(round(seconds / step)):
        assert plant.do_step(tick * step, step) == Status.OK, plant.last_reason
        rows.append({n: plant.get(n) for n in names})
    assert rows[-1]["q_shoulder"] is not rows[-2]["q_shoulder"]  # outputs are replaced, not mutated
    return {n: np.array([row[n] for row in rows]) for n in names}


def test_held_arm_stays_put_and_pushes_with_the_statics_force_growing_with_the_command():
    scales = [0.25, 0.5, 0.75, 1.0]
    commands = [(s, s) for s in scales] + [(1.0, -1.0), (-1.0, 0.0)]
    out = run_plant(commands, 30.0, held=True)
    moved = np.hypot(out["hand_x"] - REST_HAND[0], out["hand_y"] - REST_HAND[1]).max(axis=0)
    assert moved.max() < 1e-3, moved
    force = np.stack([out["force_x"][-1], out["force_y"][-1]], axis=1)
    # Statics: servo torque K a (the arm is still), hand force F with J^T F = tau (J in m/rad).
    gain = ArmPlant().variables["servo_gain"].start
    j_per_radian = jacobian(*REST_POSE) * 180 / math.pi
    expected = np.linalg.solve(j_per_radian.T, gain * np.radians(np.array(commands)).T).T
    assert np.allclose(force, expected, rtol=0.01, atol=1e-3)
    magnitude = np.linalg.norm(force[:4], axis=1)
    assert magnitude[0] > 0.1 and np.all(np.diff(magnitude) > 0)
    assert 0.3 < np.linalg.norm(force[3]) < 3  # a = 1 deg/s gives a force of order 1 N
    assert force[5, 0] > 0  # shoulder turning clockwise pushes the hand to the right (+x)
    steady = np.stack([out["force_x"][50:], out["force_y"][50:]])  # after the first second
    assert np.ptp(steady, axis=1).max() < 0.01  # a steady push, no oscillation


def test_free_arm_follows_the_commanded_joint_velocity():
    commands = np.array([(1.0, -1.0), (-0.5, 0.8), (20.0, 30.0)])
    out = run_plant(commands, 1.0, held=False)
    for joint, name in enumerate(("q_shoulder", "q_elbow")):
        velocity = (out[name][-1] - out[name][25]) / 0.5  # over the last half second
        assert np.allclose(velocity, commands[:, joint], rtol=0.02)
        # Over the whole second, the start-up lag (about M / K = 15 ms) stays inside 2 % for |a| <= 1 deg/s.
        assert np.allclose(out[name][-1, :2] - out[name][0, :2], commands[:2, joint] * 1.0, rtol=0.02)
    hand = forward(out["q_shoulder"][-1], out["q_elbow"][-1])
    assert np.allclose((out["hand_x"][-1], out["hand_y"][-1]), hand, atol=1e-4)  # the pivots hold
    assert np.all(out["force_x"] == 0) and np.all(out["force_y"] == 0)


def test_torque_limit_caps_the_servo():
    out = run_plant([(50.0, 0.0)], 0.2, held=False, torque_limit=0.05)
    # Capped torque 0.05 N.m on the stiff start: the arm cannot reach 50 deg/s within 0.2 s.
    assert 0 < out["q_shoulder"][-1, 0] - REST_POSE[0] < 0.5 * 50 * 0.2


@pytest.mark.parametrize("name, value", [("held", "clamped"), ("held", 1.0), ("q0_elbow", 30.0),
                                         ("substeps", 0), ("servo_gain", -1.0)])
def test_bad_parameter_is_one_error_naming_it(name, value):
    plant = ArmPlant()
    plant.instantiate(1)
    with pytest.raises(ComponentError, match=f"body.{name}"):
        plant.set(name, value)


def test_too_few_substeps_fail_the_step_naming_substeps():
    plant = start(ArmPlant(), 1, substeps=4)
    assert plant.do_step(0.0, 0.02) == Status.ERROR
    assert "substeps" in plant.last_reason
