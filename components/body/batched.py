"""The arm of :class:`~rhi.components.body.plant.ArmPlant` for cohorts: every trial's arm advanced by one set of numpy
calls on (B,) arrays (``rhi experiment --body batched``, ``rhi export-body --variant batched``).

The same arm as the pymunk plant: two uniform rods (its masses, lengths and inertias m l^2 / 12 about their
centres) on a shoulder pivot fixed on the torso and an elbow pivot, no gravity (a horizontal table), the same
velocity servo on the joints (:func:`servo_torque`), and for a held trial the same two-axis load cell (two
damped springs of rest length ``CELL_ARM`` anchored one to the left of the hand and one behind it,
:func:`load_cell_force`), whose reading is the springs' impulse summed over the sub-steps, divided by the step,
sign flipped (the force the arm exerts at the hand).

Where the pymunk plant simulates two free bodies held together by pivot constraints that Chipmunk's iterative
solver enforces, this arm is written in its two joint angles, where the pivots hold exactly: the two-link planar
manipulator's equations of motion, M(q) q'' + c(q, q') = tau + J(q)^T F (:func:`joint_inertia`,
:func:`velocity_forces`). Each of ``substeps`` sub-steps is Chipmunk's order: positions from the velocities
first, then the servo's torque from the velocities, then the velocities from the forces (semi-implicit Euler),
the load cell's damping taken implicitly (:func:`substep`). So the two differ by the integrators' errors (the
pivots' drift and the solver's iterations against exact joints; Chipmunk's exponential spring damping against
backward Euler's), which are bounded on the reported statistics in tests/test_body_batched.py.

The sub-steps run in C (``components/body/_arm.c``, built by the package's install: every trial's sub-steps in
one call) or, where that is not built, in numpy (:func:`substep`, a call per sub-step for all trials): the same
IEEE operations in the same order.
"""
from __future__ import annotations


import numpy as np

from .kinematics import FOREARM, SHOULDER, UPPER_ARM
from .plant import CELL_ARM, ArmPlant, checked_step
from ..component import Component, ComponentError

# the parameters' columns as the C loop takes them, per trial (the first two the step's command, rad/s)
PACKED = ("command_shoulder", "command_elbow", "gain", "limit", "upper_mass", "forearm_mass", "stiffness", "damping",
          "anchor_x_x", "anchor_x_y", "anchor_y_x", "anchor_y_y")


def c_loop():
    """``rhi.components.body._arm`` told the arm's geometry, or None (the numpy loop) where it is not built."""
    try:
        from . import _arm
    except ImportError:
        return None
    _arm.geometry(UPPER_ARM, FOREARM, SHOULDER[0], SHOULDER[1], CELL_ARM)
    return _arm


C_LOOP = c_loop()


def joint_inertia(elbow_rad, upper_mass, forearm_mass):
    """The joint-space inertia M(q) = [[m11, m12], [m12, m22]] (kg m^2) of two uniform rods in (absolute
    shoulder, relative elbow) angles: Spong, Hutchinson & Vidyasagar (2006), Robot Modeling and Control,
    sec. 7.4.1 (the two-link planar manipulator, d_ij), with centres of mass at half length and inertias
    m l^2 / 12 about them. Returns (m11, m12, m22), each broadcast over trials."""
    cos_e = np.cos(elbow_rad)
    coupling = forearm_mass * UPPER_ARM * FOREARM / 2  # m2 l1 lc2
    forearm = forearm_mass * FOREARM**2 / 3  # m2 lc2^2 + I2
    m11 = upper_mass * UPPER_ARM**2 / 3 + forearm_mass * UPPER_ARM**2 + forearm + 2 * coupling * cos_e
    m12 = forearm + coupling * cos_e
    return m11, m12, np.broadcast_to(forearm, np.shape(m11))


def velocity_forces(elbow_rad, shoulder_speed, elbow_speed, forearm_mass):
    """The Coriolis and centrifugal terms c(q, q') (N m) of the same arm, (c_shoulder, c_elbow): Spong,
    Hutchinson & Vidyasagar (2006), sec. 7.4.1, with h = -m2 l1 lc2 sin q2:
    c1 = h (2 q1' q2' + q2'^2), c2 = -h q1'^2."""
    h = -forearm_mass * UPPER_ARM * FOREARM / 2 * np.sin(elbow_rad)
    return h * (2 * shoulder_speed * elbow_speed + elbow_speed**2), -h * shoulder_speed**2


def hand_and_jacobian(shoulder_rad, elbow_rad):
    """The hand (x, y) in m and its Jacobian d(hand)/d(shoulder, elbow) in m/rad, as ((jxs, jxe), (jys, jye)):
    the two-link arm's forward kinematics (components/body/kinematics.py, in radians)."""
    forearm_angle = shoulder_rad + elbow_rad
    cos_s, sin_s, cos_f, sin_f = np.cos(shoulder_rad), np.sin(shoulder_rad), np.cos(forearm_angle), np.sin(forearm_angle)
    x_e, y_e = FOREARM * cos_f, FOREARM * sin_f
    x, y = SHOULDER[0] + UPPER_ARM * cos_s + x_e, SHOULDER[1] + UPPER_ARM * sin_s + y_e
    return (x, y), ((-UPPER_ARM * sin_s - y_e, -y_e), (UPPER_ARM * cos_s + x_e, x_e))


def servo_torque(command, speed, gain, limit):
    """The pymunk plant's velocity servo (components/body/plant.py, module docstring): joint torque
    clip(K (a - w), +-limit), N m, for commanded and actual joint velocities (rad/s)."""
    return np.clip(gain * (command - speed), -limit, limit)


def load_cell_force(hand, anchor, stiffness):
    """One load-cell spring: Chipmunk's damped spring (cpDampedSpring, its default spring force
    (restLength - dist) k) from ``anchor`` to the hand, rest length CELL_ARM. Returns the spring's force on the
    hand along its axis n (N, positive pushing the hand away from the anchor) and n (from the anchor to the
    hand), each component (B,)."""
    dx, dy = hand[0] - anchor[0], hand[1] - anchor[1]
    length = np.sqrt(dx * dx + dy * dy)  # Chipmunk's cpvlength
    return stiffness * (CELL_ARM - length), (dx / length, dy / length)


def substep(state, command, p, dt):
    """One sub-step of ``dt`` for every trial, in place on ``state`` (q1, q2, w1, w2: rad and rad/s, (B,) each);
    returns the load cells' impulses (x spring, y spring), N s, (B,) each (0 for a free trial).

    Chipmunk's order (cpSpaceStep): positions from the velocities, then velocities from the forces at the new
    positions with the servo's torque of the old velocities (semi-implicit Euler); the springs' damping
    -c (n . v) on the new velocity (backward Euler, as Chipmunk's drag acts on the velocity it leaves):
    (M + dt c J^T (n_x n_x^T + n_y n_y^T) J) w' = M w + dt (tau - c(q, w) + J^T sum_i n_i f_i).
    ``p``: the parameters as (B,) arrays (gain, limit, masses, stiffness and damping, 0 for a free trial,
    and the anchors).
    """
    q1, q2, w1, w2 = state
    q1 += w1 * dt
    q2 += w2 * dt
    tau1 = servo_torque(command[0], w1, p["gain"], p["limit"])
    tau2 = servo_torque(command[1], w2, p["gain"], p["limit"])
    m11, m12, m22 = joint_inertia(q2, p["upper_mass"], p["forearm_mass"])
    c1, c2 = velocity_forces(q2, w1, w2, p["forearm_mass"])
    hand, ((jxs, jxe), (jys, jye)) = hand_and_jacobian(q1, q2)
    fx, (nxx, nxy) = load_cell_force(hand, p["anchor_x"], p["stiffness"])
    fy, (nyx, nyy) = load_cell_force(hand, p["anchor_y"], p["stiffness"])
    # each spring's axis in joint space, g_i = J^T n_i (m/rad): its force f_i gives torques g_i f_i
    gxs, gxe = jxs * nxx + jys * nxy, jxe * nxx + jye * nxy
    gys, gye = jxs * nyx + jys * nyy, jxe * nyx + jye * nyy
    drag = dt * p["damping"]
    a11, a12, a22 = m11 + drag * (gxs * gxs + gys * gys), m12 + drag * (gxs * gxe + gys * gye), \
        m22 + drag * (gxe * gxe + gye * gye)
    b1 = m11 * w1 + m12 * w2 + dt * (tau1 - c1 + gxs * fx + gys * fy)
    b2 = m12 * w1 + m22 * w2 + dt * (tau2 - c2 + gxe * fx + gye * fy)
    determinant = a11 * a22 - a12 * a12
    w1[:] = (a22 * b1 - a12 * b2) / determinant
    w2[:] = (a11 * b2 - a12 * b1) / determinant
    # the impulses along each axis: the spring's and its damping's on the new velocity
    return dt * fx - drag * (gxs * w1 + gxe * w2), dt * fy - drag * (gys * w1 + gye * w2)


class BatchedArm(Component):
    """The pymunk plant's arm in joint coordinates, every trial in one set of numpy calls (the body contract,
    and the pymunk plant's parameters, declared as it declares them)."""

    def __init__(self, name: str = "body"):
        super().__init__(name, list(ArmPlant().variables.values()))
        self._state = np.zeros((0, 4))  # per trial: q1, q2 (rad), w1, w2 (rad/s)
        self._packed = np.zeros((0, len(PACKED)))  # per trial, PACKED's columns
        self._held = np.zeros(0, bool)

    def publish_initial(self):
        """The initial pose, as soon as the parameters are in (the brain reads it first)."""
        v = self.values
        self._publish(np.radians(v["q0_shoulder"]), np.radians(v["q0_elbow"]), np.zeros((2, self.batch_size)))

    def initialize(self):
        """The arms at rest at (q0_shoulder, q0_elbow), a held trial's hand in its load cell."""
        self.check_parameters()
        v = self.values
        q1, q2 = np.radians(v["q0_shoulder"]), np.radians(v["q0_elbow"])
        self._state = np.stack([q1, q2, np.zeros_like(q1), np.zeros_like(q2)], axis=1).astype(float)
        (x, y), _ = hand_and_jacobian(q1, q2)
        self._held = np.asarray(v["held"], bool).copy()
        self._packed = np.zeros((self.batch_size, len(PACKED)))
        for column, values in zip(PACKED[2:], (v["servo_gain"], v["torque_limit"], v["upper_arm_mass"],
                                               v["forearm_mass"], 0.0, 0.0, x - CELL_ARM, y, x, y - CELL_ARM)):
            self._packed[:, PACKED.index(column)] = values
        self._set_cells()
        self._publish(q1, q2, np.zeros((2, self.batch_size)))

    def _set_cells(self):
        """The load cells' stiffness and damping, 0 for a trial whose hand is free (no spring)."""
        v = self.values
        self._packed[:, PACKED.index("stiffness")] = np.where(self._held, v["clamp_stiffness"], 0.0)
        self._packed[:, PACKED.index("damping")] = np.where(self._held, v["clamp_damping"], 0.0)

    def parameters(self) -> dict:
        """The parameters as :func:`substep` takes them, (B,) arrays (views of the packed columns)."""
        column = {name: self._packed[:, n] for n, name in enumerate(PACKED)}
        return {"gain": column["gain"], "limit": column["limit"], "upper_mass": column["upper_mass"],
                "forearm_mass": column["forearm_mass"], "stiffness": column["stiffness"],
                "damping": column["damping"], "anchor_x": (column["anchor_x_x"], column["anchor_x_y"]),
                "anchor_y": (column["anchor_y_x"], column["anchor_y_y"])}

    def step(self, t, h):
        """Advance every arm by ``h`` in ``substeps`` sub-steps (:func:`substep`) and publish the angles (deg), the
        hand (m) and the load cell's force (N; 0 when free), as the pymunk plant does; a held arm whose
        ``release_time`` has come is let go first. StepFailure if the command is not finite, or a sub-step is
        longer than the servo's time constant (the pymunk plant's check)."""
        v = self.values
        due = self._held & (t >= v["release_time"] - 1e-9)
        if due.any():
            self._held &= ~due
            self._set_cells()
        command, substeps, dt = checked_step(self.name, v, h)
        self._packed[:, :2] = command
        command = command.T  # (2, B): the numpy sub-step's layout
        impulse = np.zeros((self.batch_size, 2))
        if C_LOOP is not None:
            C_LOOP.substeps(self._state, self._packed, impulse, self.batch_size, substeps, dt)
        else:
            state, parameters = self._state.T, self.parameters()
            for _ in range(substeps):
                jx, jy = substep(state, command, parameters, dt)
                impulse[:, 0] += jx
                impulse[:, 1] += jy
        # the springs' impulse is what the cell does to the arm; the arm exerts the opposite
        self._publish(self._state[:, 0].copy(), self._state[:, 1].copy(), -impulse.T / h)

    def check_parameters(self):
        """ComponentError if ``substeps`` differs between the trials (one loop of sub-steps serves them all)."""
        v = self.values
        if np.any(v["substeps"] != v["substeps"][0]):
            raise ComponentError(f"{self.name}.substeps = {v['substeps'].tolist()} must be the same for every "
                                 "trial (one loop of sub-steps serves them all)")

    def _publish(self, q1, q2, force):
        """Replace every output array (never mutate in place)."""
        (x, y), _ = hand_and_jacobian(q1, q2)
        self.values.update(q_shoulder=np.degrees(q1), q_elbow=np.degrees(q2), hand_x=x, hand_y=y,
                           force_x=force[0].copy(), force_y=force[1].copy())
