"""The arm plant's batched step against a per-trial reference written out here: the same numbers to the last bit.

The reference is the plant as one would write it for one trial: its own pymunk space, the servo law in Python
floats, the load cell's impulses read spring by spring through pymunk's ``Constraint.impulse``, the angles from
``Body.angle`` and the hand from ``Body.local_to_world``. The plant puts every trial in ONE space, reads and
writes the bodies with pymunk's batch calls and computes the servo in numpy on (B, 2) arrays, or runs those
sub-steps in C (components/body/_servo.c) where it is built: checked with each. Trials never interact (their
bodies share no constraint, and there are no shapes to collide), and IEEE arithmetic is element-wise, so the
two must agree exactly: any difference is a bug, not rounding (tolerance 0).
"""
import math

import numpy as np
import pymunk
import pytest

from rhi.components.body.kinematics import FOREARM, SHOULDER, UPPER_ARM
from rhi.components.body import plant as plant_module
from rhi.components.body.plant import CELL_ARM, ArmPlant
from rhi.components.component import Status

NAMES = ("q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y")


class OneTrial:
    """One trial of the arm, alone in its space, stepped with plain Python (the plant's docstring, per trial)."""

    def __init__(self, p):
        self.p, self.space = p, pymunk.Space()
        start, bodies = pymunk.Vec2d(*SHOULDER), []
        angles = (math.radians(p["q0_shoulder"]), math.radians(p["q0_shoulder"]) + math.radians(p["q0_elbow"]))
        for length, mass, angle in zip((UPPER_ARM, FOREARM), (p["upper_arm_mass"], p["forearm_mass"]), angles):
            body = pymunk.Body(mass, mass * length**2 / 12)
            direction = pymunk.Vec2d(math.cos(angle), math.sin(angle))
            body.position, body.angle = start + direction * (length / 2), angle
            bodies.append(body)
            start = start + direction * length
        self.upper, self.forearm = bodies
        self.space.add(self.upper, self.forearm, pymunk.PivotJoint(self.space.static_body, self.upper, SHOULDER),
                       pymunk.PivotJoint(self.upper, self.forearm, self.upper.local_to_world((UPPER_ARM / 2, 0.0))))
        self.cell = None
        if p["held"]:
            hand = self.forearm.local_to_world((FOREARM / 2, 0.0))
            self.cell = [pymunk.DampedSpring(self.space.static_body, self.forearm, (hand.x - dx, hand.y - dy),
                                             (FOREARM / 2, 0.0), CELL_ARM, p["clamp_stiffness"], p["clamp_damping"])
                         for dx, dy in ((CELL_ARM, 0.0), (0.0, CELL_ARM))]
            self.space.add(*self.cell)

    def step(self, t, h, command_deg):
        p = self.p
        if self.cell is not None and t >= p["release_time"] - 1e-9:
            self.space.remove(*self.cell)
            self.cell = None
        want = [math.radians(c) for c in command_deg]
        impulse, dt = [0.0, 0.0], h / p["substeps"]
        for _ in range(p["substeps"]):
            w_upper, w_forearm = self.upper.angular_velocity, self.forearm.angular_velocity
            k, cap = p["servo_gain"], p["torque_limit"]
            tau_shoulder = min(max(k * (want[0] - w_upper), -cap), cap)
            tau_elbow = min(max(k * (want[1] - (w_forearm - w_upper)), -cap), cap)
            self.upper.torque, self.forearm.torque = tau_shoulder - tau_elbow, tau_elbow
            self.space.step(dt)
            if self.cell is not None:
                impulse = [total + spring.impulse for total, spring in zip(impulse, self.cell)]
        hand = self.forearm.local_to_world((FOREARM / 2, 0.0))
        force = [-i / h for i in impulse]  # what the arm exerts; -0.0 without a load cell, as the plant publishes
        return (math.degrees(self.upper.angle), math.degrees(self.forearm.angle - self.upper.angle),
                hand.x, hand.y, force[0], force[1])


@pytest.mark.parametrize("loop", ["c", "numpy"])
def test_batched_plant_equals_one_space_per_trial_to_the_last_bit(loop, monkeypatch):
    if loop == "numpy":
        monkeypatch.setattr(plant_module, "C_LOOP", None)
    elif plant_module.C_LOOP is None:
        pytest.skip("rhi.components.body._servo is not built (tests/test_body_cloop.py says so)")
    # Five trials that differ in everything a trial may: held or free, pose, masses, gain, limit, load cell,
    # and one held trial let go mid-run; commands that saturate the torque limit in one trial.
    parameters = {"held": [True, False, True, True, False], "q0_shoulder": [57.0, 40.0, 70.0, 57.0, 90.0],
                  "q0_elbow": [-80.0, -60.0, -100.0, -80.0, -45.0], "upper_arm_mass": [2.0, 2.5, 1.8, 2.0, 2.0],
                  "forearm_mass": [1.5, 1.2, 1.5, 1.7, 1.5], "servo_gain": [20.0, 15.0, 25.0, 20.0, 20.0],
                  "torque_limit": [10.0, 10.0, 0.05, 10.0, 10.0], "clamp_stiffness": [2e4, 2e4, 1e4, 3e4, 2e4],
                  "clamp_damping": [300.0, 300.0, 200.0, 400.0, 300.0],
                  "release_time": [np.inf, np.inf, 0.3, np.inf, np.inf]}
    steps, h, batch = 40, 0.02, 5
    plant = ArmPlant()
    plant.instantiate(batch)
    for name, value in parameters.items():
        plant.set(name, np.array(value))
    plant.enter_initialization_mode()
    plant.exit_initialization_mode()
    substeps = int(plant.values["substeps"][0])  # the default, 20
    trials = [OneTrial({**{k: v[n] if k == "held" else float(v[n]) for k, v in parameters.items()},
                        "substeps": substeps}) for n in range(batch)]
    rng = np.random.default_rng(3)
    commands = rng.uniform(-1.0, 1.0, (steps, batch, 2)) * np.array([1.0, 1.0, 60.0, 1.0, 20.0])[None, :, None]
    for tick in range(steps):
        plant.set("u_shoulder", commands[tick, :, 0])
        plant.set("u_elbow", commands[tick, :, 1])
        assert plant.do_step(tick * h, h) == Status.OK, plant.last_reason
        expected = np.array([trial.step(tick * h, h, commands[tick, n]) for n, trial in enumerate(trials)])
        got = np.stack([plant.get(name) for name in NAMES], axis=1)
        assert got.tobytes() == expected.tobytes(), (tick, got - expected)
    assert np.all(plant.get("force_x")[[1, 2, 4]] == 0)  # free, released, free: no load cell
