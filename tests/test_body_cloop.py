"""The arm plant's sub-step loop in C (components/body/_servo.c) against its numpy loop: the same bits.

The two are one servo law (components/body/plant.py's docstring) written twice with the same IEEE double operations
in the same order, on the same Chipmunk calls, so they must agree exactly: tolerance 0, any difference is a bug.
np.maximum and np.minimum choose between equal operands (+0 and -0) in a way of their own, which the C copies; the
outputs hardly show a zero's sign (Chipmunk adds the torque to a speed), so the torques handed to Chipmunk are
compared too, recorded on their way in.
"""
import sys

import numpy as np
import pymunk
import pymunk.batch
import pytest
from pymunk._chipmunk import ffi, lib as chipmunk

from rhi.components.body import plant as plant_module
from rhi.components.body.plant import ArmPlant, address
from rhi.components.component import Status

NAMES = ("q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y")
STATE = (pymunk.batch.BodyFields.POSITION | pymunk.batch.BodyFields.ANGLE | pymunk.batch.BodyFields.VELOCITY
         | pymunk.batch.BodyFields.ANGULAR_VELOCITY)
# Eight trials: held, free, and two held let go at different steps; a zero gain (the servo's torque 0 times an
# error: a signed zero) and a zero limit (every torque clipped to +-0); limits the commands hit.
PARAMETERS = {"held": [True, False, True, True, False, True, True, False],
              "q0_shoulder": [57.0, 40.0, 70.0, 57.0, 90.0, 60.0, 50.0, 57.0],
              "q0_elbow": [-80.0, -60.0, -100.0, -80.0, -45.0, -90.0, -70.0, -80.0],
              "upper_arm_mass": [2.0, 2.5, 1.8, 2.0, 2.0, 2.2, 2.0, 1.9],
              "forearm_mass": [1.5, 1.2, 1.5, 1.7, 1.5, 1.4, 1.5, 1.6],
              "servo_gain": [20.0, 15.0, 25.0, 0.0, 20.0, 20.0, 0.0, 20.0],
              "torque_limit": [10.0, 10.0, 0.05, 10.0, 0.0, 10.0, 0.0, 0.5],
              "release_time": [np.inf, np.inf, 0.3, np.inf, np.inf, 0.1, np.inf, np.inf]}
STEPS, H = 30, 0.02


def commands():
    """(STEPS, trial, joint) deg/s: random, some far past the limits, trial 1 at 0 and trial 4 at -0, every trial
    at 0 on some steps."""
    rng = np.random.default_rng(5)
    scale = np.array([1.0, 1.0, 60.0, 1.0, 1.0, 5.0, 1.0, 200.0])[None, :, None]
    command = rng.uniform(-1.0, 1.0, (STEPS, len(scale[0]), 2)) * scale
    command[:, 1], command[:, 4] = 0.0, -0.0
    command[::7] = 0.0
    return command


def plant():
    arm = ArmPlant()
    arm.instantiate(len(PARAMETERS["held"]))
    for name, value in PARAMETERS.items():
        arm.set(name, np.array(value))
    arm.enter_initialization_mode()
    arm.exit_initialization_mode()
    return arm


def run(loop, monkeypatch, record):
    """Step a fresh plant through commands() with ``loop`` (None: numpy); the outputs and the bodies' state after
    each step, and through ``record`` the torques of each sub-step."""
    monkeypatch.setattr(plant_module, "C_LOOP", loop)
    arm, outputs = plant(), []
    record.arm = arm
    for tick, command in enumerate(commands()):
        arm.set("u_shoulder", command[:, 0])
        arm.set("u_elbow", command[:, 1])
        assert arm.do_step(tick * H, H) == Status.OK, arm.last_reason
        state = pymunk.batch.Buffer()
        pymunk.batch.get_space_bodies(arm.space, STATE, state)
        outputs.append(np.concatenate([np.stack([arm.get(name) for name in NAMES]).ravel(),
                                       np.frombuffer(state.float_buf())]))
    monkeypatch.undo()
    return np.array(outputs)


class Torques(list):
    """Per sub-step, the torques handed to Chipmunk: (upper arm, forearm) per trial, then the static body's."""
    arm = None

    def numpy_spy(self, monkeypatch):
        real = pymunk.batch.set_space_bodies

        def spy(space, fields, buffers):
            if fields == pymunk.batch.BodyFields.TORQUE:
                torque = np.frombuffer(buffers.float_buf())
                rest = np.delete(torque, self.arm._order)
                self.append(np.concatenate([torque[self.arm._order], rest]))
            real(space, fields, buffers)
        monkeypatch.setattr(pymunk.batch, "set_space_bodies", spy)

    def c_spy(self, loop):
        """Bind ``loop`` to a cpBodySetTorque that records, then sets (plant_module.c_loop() binds it back)."""
        calls = []

        @ffi.callback("void(struct cpBody *, double)")
        def spy(body, value):
            calls.append((address(body), value))
            chipmunk.cpBodySetTorque(body, value)
            if address(body) == address(self.arm.space.static_body._body):  # the last of a sub-step
                slot = {body: n for n, body in enumerate(self.arm._addresses.tolist())}
                torque = np.zeros(len(calls))
                for body_address, torque_value in calls:
                    torque[slot.get(body_address, len(calls) - 1)] = torque_value
                self.append(torque)
                calls.clear()
        functions = [ffi.addressof(chipmunk, name) for name in plant_module.C_FUNCTIONS]
        functions[2] = spy
        loop.bind(*map(address, functions))
        return spy


def test_the_install_built_the_c_loop():
    assert plant_module.C_LOOP is not None, "rhi.components.body._servo is not built: pip install -e . builds it"


def test_c_loop_equals_numpy_loop_to_the_bit(monkeypatch):
    loop = plant_module.C_LOOP
    if loop is None:
        pytest.skip("rhi.components.body._servo is not built")
    numpy_torques, c_torques = Torques(), Torques()
    numpy_torques.numpy_spy(monkeypatch)
    reference = run(None, monkeypatch, numpy_torques)
    spy = c_torques.c_spy(loop)
    try:
        got = run(loop, monkeypatch, c_torques)
    finally:
        plant_module.c_loop()  # Chipmunk's own cpBodySetTorque again
    del spy
    assert got.tobytes() == reference.tobytes(), np.argwhere(got.view(np.uint64) != reference.view(np.uint64))[:5]
    numpy_torques, c_torques = np.array(numpy_torques), np.array(c_torques)
    assert c_torques.shape == numpy_torques.shape == (STEPS * 20, 2 * len(PARAMETERS["held"]) + 1)
    assert c_torques.tobytes() == numpy_torques.tobytes()
    # The signed zeros were there to get wrong: -0 torques (zero gain), and +0 ones from a zero limit.
    zero = c_torques == 0
    assert np.any(zero & np.signbit(c_torques)) and np.any(zero & ~np.signbit(c_torques))
    # And the C loop with Chipmunk's own functions again gives the same bits as with the recording ones.
    assert run(loop, monkeypatch, Torques()).tobytes() == reference.tobytes()


def test_numpy_loop_when_the_c_module_is_absent(monkeypatch):
    import rhi.components.body

    monkeypatch.setitem(sys.modules, "rhi.components.body._servo", None)  # so its import raises ImportError
    monkeypatch.delattr(rhi.components.body, "_servo", raising=False)
    assert plant_module.c_loop() is None
    monkeypatch.setattr(plant_module, "C_LOOP", plant_module.c_loop())
    calls = []
    numpy_loop = ArmPlant._substeps_numpy
    monkeypatch.setattr(ArmPlant, "_substeps_numpy", lambda *args: calls.append(1) or numpy_loop(*args))
    arm = plant()
    assert arm.do_step(0.0, H) == Status.OK and calls == [1]
