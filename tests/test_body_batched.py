"""The batched arm (components/body/batched.py) against independent truths: the Lagrangian of two uniform rods by
finite differences, energy conservation of the free arm without servo, the statics of the held arm, and the
pymunk arm (an independent implementation of the same arm) on free motion."""
import math

import numpy as np
import pytest

from rhi.components.body import batched
from rhi.components.body.batched import BatchedArm, joint_inertia, substep, velocity_forces
from rhi.components.body.kinematics import FOREARM, REST_POSE, UPPER_ARM
from rhi.components.body.plant import ArmPlant
from rhi.components.body.variants import held_hand_force

UPPER_MASS, FOREARM_MASS = 2.0, 1.5  # kg, the shipped arm's


def kinetic_energy(q, w, upper_mass=UPPER_MASS, forearm_mass=FOREARM_MASS):
    """T of the two rods from their centres' velocities and their spins (J): sum m |v_c|^2 / 2 + I w^2 / 2 with
    I = m l^2 / 12, the centres' velocities differentiated by hand from c1 = (l1/2) e^{i q1},
    c2 = l1 e^{i q1} + (l2/2) e^{i (q1 + q2)} (complex numbers for the plane)."""
    q1, q2 = q
    w1, w2 = w
    v1 = 1j * w1 * UPPER_ARM / 2 * np.exp(1j * q1)
    v2 = 1j * w1 * UPPER_ARM * np.exp(1j * q1) + 1j * (w1 + w2) * FOREARM / 2 * np.exp(1j * (q1 + q2))
    return (upper_mass * abs(v1) ** 2 + forearm_mass * abs(v2) ** 2) / 2 + \
        (upper_mass * UPPER_ARM**2 * w1**2 + forearm_mass * FOREARM**2 * (w1 + w2) ** 2) / 24


@pytest.mark.parametrize("q", [(2.58, -1.59), (0.3, -0.2), (1.0, -3.0), (-0.5, 2.4)])
def test_inertia_and_velocity_forces_are_the_lagrangian_s_by_finite_differences(q):
    w = np.array([1.3, -2.1])
    unit = np.eye(2)
    # M_ij = d2T / dw_i dw_j: T is quadratic in w, so the central second difference with step 1 is exact up to
    # rounding (1e-16 of T ~ 1 J), hence 1e-12.
    hessian = np.array([[(kinetic_energy(q, w + unit[i] + unit[j]) - kinetic_energy(q, w + unit[i] - unit[j])
                          - kinetic_energy(q, w - unit[i] + unit[j]) + kinetic_energy(q, w - unit[i] - unit[j])) / 4
                         for j in range(2)] for i in range(2)])
    m11, m12, m22 = joint_inertia(q[1], UPPER_MASS, FOREARM_MASS)
    assert np.array([[m11, m12], [m12, m22]]) == pytest.approx(hessian, abs=1e-12)
    # Euler-Lagrange at zero acceleration: c_i = sum_j d2T/(dw_i dq_j) w_j - dT/dq_i. dT/dw_i is a central
    # difference with step 1 (exact, T quadratic in w); the q derivatives central differences with step 1e-5,
    # whose truncation (h^2/6 T''' ~ 1e-10 J) and rounding (1e-16 / 1e-5) stay below 1e-8.
    h = 1e-5

    def momentum(qq, i):
        return (kinetic_energy(qq, w + unit[i]) - kinetic_energy(qq, w - unit[i])) / 2

    def along(f, j):
        return (f(np.array(q) + h * unit[j]) - f(np.array(q) - h * unit[j])) / (2 * h)
    expected = [sum(along(lambda qq: momentum(qq, i), j) * w[j] for j in range(2))
                - along(lambda qq: kinetic_energy(qq, w), i) for i in range(2)]
    assert np.array(velocity_forces(q[1], w[0], w[1], FOREARM_MASS)) == pytest.approx(expected, abs=1e-8)


def free_parameters(n):
    """No servo (gain 0), no load cell (stiffness 0; the anchors anywhere off the hand)."""
    zero = np.zeros(n)
    return {"gain": zero, "limit": zero, "upper_mass": np.full(n, UPPER_MASS), "forearm_mass": np.full(n, FOREARM_MASS),
            "stiffness": zero, "damping": zero, "anchor_x": (np.full(n, -5.0), zero), "anchor_y": (zero, np.full(n, -5.0))}


def energy_error(dt, seconds=1.0):
    """The largest |T - T0| / T0 of a free arm thrown at (2, -3) rad/s from the rest pose, over ``seconds``."""
    state = np.array([[math.radians(REST_POSE[0])], [math.radians(REST_POSE[1])], [2.0], [-3.0]])
    start = kinetic_energy(state[:2, 0], state[2:, 0])
    worst = 0.0
    for _ in range(round(seconds / dt)):
        substep(state, np.zeros((2, 1)), free_parameters(1), dt)
        worst = max(worst, abs(kinetic_energy(state[:2, 0], state[2:, 0]) - start) / start)
    return worst


def test_the_free_arm_without_servo_conserves_energy_to_first_order_in_the_step():
    # Semi-implicit Euler is a first-order method: its energy error is O(dt) (bounded, no secular drift), so
    # halving the step halves it -- the ratio 2, within 20 % for the higher orders at these steps.
    coarse, fine = energy_error(1e-3), energy_error(5e-4)
    assert coarse / fine == pytest.approx(2.0, rel=0.2)
    # and the sub-step of the shipped arm (0.02 s / 20) keeps it within dt * |w| (3e-3 here, the first-order
    # term's scale), while the arm turns more than a full revolution of the elbow over the second
    assert coarse < 1e-3 * 3.0


def run_arm(cls, held, command_deg_s, steps, batch=2, **parameters):
    """``cls`` stepped ``steps`` steps of 0.02 s under a constant command; each output per step, (steps, name, B)."""
    arm = cls()
    arm.instantiate(batch)
    arm.setup_experiment(0.0)
    arm.enter_initialization_mode()
    arm.set("held", np.full(batch, held))
    for name, value in parameters.items():
        arm.set(name, np.full(batch, value))
    arm.exit_initialization_mode()
    names, out = ("q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y"), []
    for step in range(steps):
        arm.set("u_shoulder", np.full(batch, command_deg_s[0]))
        arm.set("u_elbow", np.full(batch, command_deg_s[1]))
        arm.do_step(step * 0.02, 0.02)
        out.append([np.array(arm.get(name)) for name in names])
    return np.array(out)


def test_the_held_arm_settles_on_the_servo_s_static_push():
    command = (0.8, -0.5)  # deg/s, within the brain's action limit
    out = run_arm(BatchedArm, True, command, 60)
    shoulder, elbow = out[-1, 0], out[-1, 1]
    statics = held_hand_force(shoulder, elbow, np.tile(command, (2, 1)), np.full(2, 20.0), np.full(2, 10.0))
    # The statics F = J^-T K a holds at zero speed; the load cell lets the hand sit F / k = 1e-4 m off its
    # place, which moves J by ~1e-4 / 0.37 relative, hence 1e-3.
    assert out[-1, 4:].T == pytest.approx(statics, rel=1e-3)
    assert out[-1, 2:4] == pytest.approx(out[0, 2:4], abs=1e-4)  # the hand stays put (F / k = 1e-4 m)


def test_the_free_arm_follows_the_pymunk_arm():
    # The same servo on the same rods: the two integrators differ by the pivots' drift in Chipmunk (its joints
    # are iterated, this arm's are exact); 1e-5 deg is 500 times below the fast decoder's relinearisation step
    # (decoder.relinearise_tolerance, 0.005 deg), the smallest angle the agent acts on.
    command = (0.9, -0.6)
    mine, pymunk_s = run_arm(BatchedArm, False, command, 150), run_arm(ArmPlant, False, command, 150)
    assert mine[:, :2] == pytest.approx(pymunk_s[:, :2], abs=1e-5)
    assert np.all(mine[:, 4:] == 0.0)
    # and it moved as commanded: 150 steps of 0.02 s at 0.9 deg/s, less the servo's lag (tau = m / K ~ 10 ms)
    assert mine[-1, 0] - REST_POSE[0] == pytest.approx(0.9 * 3.0, abs=0.9 * 0.02)


def test_a_held_arm_let_go_moves_and_reads_no_force():
    out = run_arm(BatchedArm, True, (0.9, 0.0), 40, release_time=0.4)
    assert np.all(out[:20, 4] != 0.0) and np.all(out[20:, 4:] == 0.0)
    assert out[-1, 0, 0] - out[19, 0, 0] == pytest.approx(0.9 * 0.4, abs=0.9 * 0.02)


def test_too_few_substeps_fail_the_step_naming_substeps():
    arm = BatchedArm()
    arm.instantiate(1)
    arm.setup_experiment(0.0)
    arm.enter_initialization_mode()
    arm.set("substeps", np.array([2]))
    arm.exit_initialization_mode()
    with pytest.raises(Exception, match="substeps = 2 is too few"):
        arm.step(0.0, 0.02)


def test_the_batched_arm_declares_the_pymunk_arm_s_variables():
    assert BatchedArm().variables == ArmPlant().variables


def test_the_batched_arm_is_a_registered_body_run_in_process():
    from rhi.master.tasks.illusion.runner import body_factory

    make, declared = body_factory("batched")
    assert type(make()) is BatchedArm and declared == set(ArmPlant().variables)
    assert body_factory(None) == (None, None)  # the default stays the pymunk arm (wiring.scenario's)


def test_the_c_loop_is_the_numpy_loop_to_the_bit(monkeypatch):
    if batched.C_LOOP is None:
        pytest.skip("rhi.components.body._arm is not built (the batched arm runs its numpy loop)")
    angles = np.linspace(-7.0, 7.0, 10001)
    if not (np.array_equal(np.sin(angles), [math.sin(a) for a in angles])
            and np.array_equal(np.cos(angles), [math.cos(a) for a in angles])):
        pytest.skip("numpy's sin and cos here are not libm's (the C loop's): the loops agree to their rounding")
    # The same IEEE operations in the same order (no FMA contraction): any difference is a bug (tolerance 0).
    # Held, free and let go mid-run; a command that saturates the torque limit in the free arm.
    runs = {}
    for loop in ("c", "numpy"):
        if loop == "numpy":
            monkeypatch.setattr(batched, "C_LOOP", None)
        runs[loop] = [run_arm(BatchedArm, True, (0.7, -0.4), 60, release_time=0.6),
                      run_arm(BatchedArm, False, (40.0, -30.0), 30, torque_limit=0.05)]
    for c_run, numpy_run in zip(runs["c"], runs["numpy"]):
        assert np.array_equal(c_run, numpy_run)
