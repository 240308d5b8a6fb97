"""The body plant: a 2-link planar arm simulated in pymunk, driven by a joint-velocity servo.

The upper arm hangs on a shoulder pivot on the static torso, the forearm on an elbow
pivot; the table is horizontal, so there is no gravity. The brain's action (commanded
joint velocities, deg/s) drives a velocity servo with finite gain and a torque limit:

    tau_shoulder = clip(K (a_shoulder - w_shoulder), +-limit)   on the upper arm, against the torso
    tau_elbow    = clip(K (a_elbow - w_elbow), +-limit)         on the forearm, against the upper arm

Two modes, per trial (the ``held`` parameter):
- free: the arm moves under the servo (a held arm becomes free at ``release_time``: its load cell goes);
- held: the hand is clamped to the table at its initial position by a stiff two-axis
  load cell (two pymunk DampedSprings, one along x, one along y). The reported force is
  the load cell's reading: the springs' constraint impulses summed over the sub-steps,
  divided by the step, with the sign flipped to give the force the ARM exerts at the
  hand (+x = to the right). The hand moves only by force / stiffness (0.1 mm at 2 N).

Servo gain: held still, the servo torque is K * a, and the hand force is J^-T K a
(J = hand Jacobian). At the rest pose that is about 0.03-0.07 N per (deg/s) per unit K,
so K = 20 N.m.s/rad gives 0.5-1.3 N for a = 1 deg/s, the brain's largest action.

The servo is explicit, so a sub-step dt must satisfy dt * K / m_min <= 1, m_min the
smallest eigenvalue of the arm's joint-space inertia at the current elbow angle (checked
every step). At 0.02 s with the defaults that needs 8 sub-steps at rest, 17 at the
straightest elbow of the decoder training range (rest + 50 deg) and 27 with the arm
straight; the default is 20. Too few fail the step with a message naming ``substeps``.

The sub-steps run in C (``components/body/_servo.c``, built by the package's install, calling Chipmunk's
functions through pymunk's cffi module) or, where that is not built, in numpy (``ArmPlant._substeps_numpy``):
two implementations of the law above with the same IEEE operations in the same order, so the same bits
(``tests/test_body_cloop.py``).
"""
from __future__ import annotations

import math

import numpy as np
import pymunk
import pymunk.batch
from pymunk.batch import BodyFields
from pymunk._chipmunk import ffi, lib as chipmunk  # Chipmunk's own calls (see _substeps_numpy, c_loop)

from .kinematics import FOREARM, REST_HAND, REST_POSE, SHOULDER, UPPER_ARM, forward
from ..component import Component, ComponentError, StepFailure
from ..variables import Variable

CELL_ARM = 1.0  # m, length of each load-cell spring (long, so a sideways deflection barely loads it)

# The Chipmunk functions the C loop calls, with the C types it calls them with (cpFloat a double).
C_FUNCTIONS = {"cpSpaceStep": "void(*)(struct cpSpace *, double)",
               "cpBodyGetAngularVelocity": "double(*)(struct cpBody *)",
               "cpBodySetTorque": "void(*)(struct cpBody *, double)",
               "cpConstraintGetImpulse": "double(*)(struct cpConstraint *)"}


def address(cdata) -> int:
    """A cffi pointer's address, as the C loop takes it."""
    return int(ffi.cast("uintptr_t", cdata))


def c_loop():
    """``rhi.components.body._servo`` bound to pymunk's Chipmunk, or None (the numpy loop) where it is not built,
    pymunk's functions are not of the types it calls, or numpy's maximum and minimum here choose otherwise than
    it does between equal operands (+0 and -0) or a NaN (it follows numpy's x86-64 kernels)."""
    try:
        from . import _servo
    except ImportError:
        return None
    functions = [ffi.addressof(chipmunk, name) for name in C_FUNCTIONS]
    if [ffi.typeof(f).cname for f in functions] != list(C_FUNCTIONS.values()):
        return None
    a = np.array([[0.0, -0.0], [-0.0, 0.0], [np.nan, 1.0], [1.0, 2.0]])  # the step's shapes: (B, 2) and (B, 1)
    b = np.array([[-0.0], [0.0], [1.0], [np.nan]])
    for numpy_op, chooses in ((np.maximum, lambda x, y: x > y), (np.minimum, lambda x, y: x < y)):
        like_c = [[x if math.isnan(x) or chooses(x, y) else y for x in row]
                  for row, (y,) in zip(a.tolist(), b.tolist())]
        if numpy_op(a, b).tobytes() != np.array(like_c).tobytes():
            return None
    _servo.bind(*map(address, functions))
    return _servo


C_LOOP = c_loop()


def state_output(name, unit, description, start):
    """An output of the arm's state: a Real that depends on no input (``depends_on=()``).

    Parameters
    ----------
    name, unit, description : str
        As for :class:`~rhi.components.variables.Variable`.
    start : float
        Its start value, in ``unit``.

    Returns
    -------
    Variable
    """
    return Variable(name, "output", start=start, unit=unit, description=description, depends_on=())


def checked_step(name: str, values, h: float):
    """A step's commanded joint velocities and its sub-steps, checked: StepFailure if the command is not finite,
    or a sub-step is longer than the servo's time constant (the explicit servo is stable only below it).

    Parameters
    ----------
    name : str
        The plant's instance name (for the message).
    values : dict
        The plant's values: ``u_shoulder``, ``u_elbow`` (deg/s), ``substeps``, ``servo_gain``, the rods' masses and
        ``q_elbow``.
    h : float
        The step, s.

    Returns
    -------
    tuple
        The command ((B, 2) rad/s, shoulder and elbow), the sub-steps per step and their length (s).
    """
    command = np.radians(np.stack([values["u_shoulder"], values["u_elbow"]], axis=1))
    if not np.all(np.isfinite(command)):
        raise StepFailure(f"{name}: commanded velocity is not finite: {np.degrees(command).tolist()}")
    substeps = int(values["substeps"][0])
    dt = h / substeps
    rate = values["servo_gain"] / smallest_inertia(values["upper_arm_mass"], values["forearm_mass"], values["q_elbow"])
    if np.any(dt * rate > 1.0):
        raise StepFailure(f"{name}.substeps = {substeps} is too few for servo_gain: a sub-step of "
                          f"{dt:.3g} s exceeds the servo time constant {1 / rate.max():.3g} s; "
                          f"use substeps >= {math.ceil(h * rate.max())}")
    return command, substeps, dt


def smallest_inertia(upper_mass, forearm_mass, elbow_deg):
    """Smallest eigenvalue (kg m^2) of the joint-space inertia M of two uniform rods at ``elbow_deg``.

    M = [[a + 2b cos e, c + b cos e], [c + b cos e, c]] in (shoulder, elbow) coordinates;
    vectorised over trials. It is smallest with the arm straight or folded (cos^2 e = 1).
    """
    upper_mass, forearm_mass, cos_e = np.broadcast_arrays(upper_mass, forearm_mass, np.cos(np.radians(elbow_deg)))
    c = forearm_mass * FOREARM**2 / 3
    a = upper_mass * UPPER_ARM**2 / 3 + forearm_mass * UPPER_ARM**2 + c
    b = forearm_mass * UPPER_ARM * FOREARM / 2
    top, off, bottom = a + 2 * b * cos_e, c + b * cos_e, np.broadcast_to(c, cos_e.shape)
    inertia = np.stack([np.stack([top, off], -1), np.stack([off, bottom], -1)], -2)
    return np.linalg.eigvalsh(inertia)[..., 0]


class ArmPlant(Component):
    """The arm (body FMU contract of docs/design.md): joint-velocity command in, angles, hand and force out."""

    def __init__(self, name: str = "body"):
        super().__init__(name, [
            Variable("u_shoulder", "input", start=0.0, unit="deg/s", description="commanded shoulder velocity a"),
            Variable("u_elbow", "input", start=0.0, unit="deg/s", description="commanded elbow velocity a"),
            state_output("q_shoulder", "deg", "shoulder angle: upper arm from +x (proprioception s_p)", REST_POSE[0]),
            state_output("q_elbow", "deg", "elbow angle: forearm relative to upper arm (s_p)", REST_POSE[1]),
            state_output("hand_x", "m", "hand position x (right of the body midline)", REST_HAND[0]),
            state_output("hand_y", "m", "hand position y (forward of the shoulder line)", REST_HAND[1]),
            state_output("force_x", "N", "force the held arm exerts at the hand along +x (0 when free)", 0.0),
            state_output("force_y", "N", "force the held arm exerts at the hand along +y (0 when free)", 0.0),
            Variable("held", "parameter", "Boolean", start=True,
                     description="true: hand clamped on the table (illusion); false: the arm moves freely"),
            Variable("q0_shoulder", "parameter", start=REST_POSE[0], unit="deg", description="initial shoulder angle"),
            Variable("q0_elbow", "parameter", start=REST_POSE[1], unit="deg", min=-180.0, max=0.0,
                     description="initial elbow angle (elbow-outward branch)"),
            Variable("substeps", "parameter", "Integer", start=20, min=1, max=10000, unit="1",
                     description="pymunk steps per communication step"),
            Variable("servo_gain", "parameter", start=20.0, min=0.0, unit="N.m.s/rad",
                     description="velocity servo gain K: torque per joint-velocity error"),
            Variable("torque_limit", "parameter", start=10.0, min=0.0, unit="N.m",
                     description="largest servo torque at each joint"),
            Variable("upper_arm_mass", "parameter", start=2.0, min=1e-3, unit="kg",
                     description="upper arm mass (uniform rod)"),
            Variable("forearm_mass", "parameter", start=1.5, min=1e-3, unit="kg",
                     description="forearm and hand mass (uniform rod)"),
            Variable("clamp_stiffness", "parameter", start=2.0e4, min=1.0, unit="N/m",
                     description="stiffness of the load cell holding the hand, per axis"),
            Variable("clamp_damping", "parameter", start=300.0, min=0.0, unit="N.s/m",
                     description="damping of the load cell, per axis"),
            Variable("release_time", "parameter", start=np.inf, min=0.0, unit="s",
                     description="held: the load cell lets the hand go at the first step from this time on "
                                 "(inf: never; reaching after the illusion)"),
        ])
        self.space: pymunk.Space | None = None
        self._arms: list[tuple[pymunk.Body, pymunk.Body]] = []
        self._cells: list[tuple[pymunk.DampedSpring, pymunk.DampedSpring] | None] = []
        self._pins: list[tuple[pymunk.PivotJoint, pymunk.PivotJoint]] = []  # (shoulder, elbow) per trial
        self._held, self._springs = np.zeros(0, int), []  # see _held_springs
        self._spring_addresses = np.zeros(0, np.uint64)  # the springs as the C loop takes them (_held_springs)
        self._addresses = np.zeros(0, np.uint64)  # (upper arm, forearm) per trial as Chipmunk bodies, for the C loop
        self._order, self._regular, self._bodies = np.zeros(0, int), True, 0  # the space's bodies (initialize)

    # -- set-up ------------------------------------------------------------------------------
    def publish_initial(self):
        """The initial pose, as soon as the parameters are in (the brain reads it first)."""
        q0 = self.values["q0_shoulder"], self.values["q0_elbow"]
        hand_x, hand_y = forward(*q0)
        self.values.update(q_shoulder=q0[0].copy(), q_elbow=q0[1].copy(), hand_x=hand_x, hand_y=hand_y)

    def check_parameters(self):
        """ComponentError if ``substeps`` differs between the trials (they share one pymunk space)."""
        v = self.values
        if np.any(v["substeps"] != v["substeps"][0]):
            raise ComponentError(f"{self.name}.substeps = {v['substeps'].tolist()} must be the same for every "
                                 f"trial (the trials share one pymunk space)")

    def initialize(self):
        """Build the pymunk space, an arm per trial at (q0_shoulder, q0_elbow) and a held trial's hand in its load
        cell, and publish the state with zero force.
        """
        self.check_parameters()
        v = self.values
        self.space = pymunk.Space()
        self.space.gravity = (0.0, 0.0)  # a horizontal table
        self._arms, self._cells, self._pins = [], [], []
        for trial in range(self.batch_size):
            upper, forearm = self._build_arm(trial)
            cell = None
            if v["held"][trial]:
                hand = forearm.local_to_world((FOREARM / 2, 0.0))
                stiffness, damping = float(v["clamp_stiffness"][trial]), float(v["clamp_damping"][trial])
                cell = tuple(pymunk.DampedSpring(self.space.static_body, forearm, (hand.x - dx, hand.y - dy),
                                                 (FOREARM / 2, 0.0), CELL_ARM, stiffness, damping)
                             for dx, dy in ((CELL_ARM, 0.0), (0.0, CELL_ARM)))
                self.space.add(*cell)
            self._arms.append((upper, forearm))
            self._cells.append(cell)
        upper, forearm, self._bodies = self._slots()
        # The space's body order as (upper arm, forearm) per trial; regular (0, 1, 2, 3, ...) as the arms are added,
        # when the batch buffers are (B, 2) views.
        self._order = np.stack([upper, forearm], axis=1).reshape(-1)
        self._regular = bool(np.array_equal(self._order, np.arange(2 * self.batch_size)))
        self._addresses = np.array([address(body._body) for arm in self._arms for body in arm], dtype=np.uint64)
        self._held_springs()
        self._publish(np.zeros((self.batch_size, 2)))

    def _slots(self):
        """(upper arm's, forearm's) positions, per trial, in the space's body order (pymunk's batch calls), and the
        number of bodies those calls walk (the arms and the space's static body)."""
        ids = pymunk.batch.Buffer()
        pymunk.batch.get_space_bodies(self.space, BodyFields.BODY_ID, ids)
        slot = {body_id: n for n, body_id in enumerate(memoryview(ids.int_buf()).cast("P"))}
        return *(np.array([slot[arm[part].id] for arm in self._arms], dtype=int) for part in (0, 1)), len(slot)

    def _build_arm(self, trial):
        v = self.values
        shoulder_angle = math.radians(v["q0_shoulder"][trial])
        forearm_angle = shoulder_angle + math.radians(v["q0_elbow"][trial])
        bodies = []
        start = pymunk.Vec2d(*SHOULDER)
        for length, mass, angle in ((UPPER_ARM, v["upper_arm_mass"][trial], shoulder_angle),
                                    (FOREARM, v["forearm_mass"][trial], forearm_angle)):
            body = pymunk.Body(float(mass), float(mass) * length**2 / 12)  # uniform rod about its centre
            direction = pymunk.Vec2d(math.cos(angle), math.sin(angle))
            body.position, body.angle = start + direction * (length / 2), angle
            bodies.append(body)
            start = start + direction * length
        upper, forearm = bodies
        shoulder_pin = pymunk.PivotJoint(self.space.static_body, upper, SHOULDER)
        elbow_pin = pymunk.PivotJoint(upper, forearm, upper.local_to_world((UPPER_ARM / 2, 0.0)))
        self.space.add(upper, forearm, shoulder_pin, elbow_pin)
        self._pins.append((shoulder_pin, elbow_pin))
        return upper, forearm

    # -- stepping ------------------------------------------------------------------------------
    def step(self, t, h):
        """Advance every arm by ``h`` in ``substeps`` pymunk sub-steps under the velocity servo, and publish the
        angles (deg), the hand (m) and the load cell's force (N; 0 when free).

        A held arm whose ``release_time`` has come is let go first. StepFailure if the command is not finite, or
        if a sub-step is longer than the servo's time constant (too few ``substeps``).

        Parameters
        ----------
        t, h : float
            The step's start and size, s.
        """
        v = self.values
        self._release(t)
        command, substeps, dt = checked_step(self.name, v, h)
        if C_LOOP is None:
            impulses = self._substeps_numpy(command, substeps, dt)
        else:  # pymunk's Space.step adds to cpSpaceStep only a check of new bodies' masses (positive here by
            # construction) and what callbacks add or remove (this space has none)
            impulses = np.zeros(len(self._springs))
            want_gain_cap = [np.ascontiguousarray(x, float) for x in (command, v["servo_gain"], v["torque_limit"])]
            C_LOOP.substeps(address(self.space._space), address(self.space.static_body._body), self._addresses,
                            *want_gain_cap, self._spring_addresses, impulses, substeps, dt)
        force = np.zeros((self.batch_size, 2))
        force[self._held] = impulses.reshape(-1, 2)
        # The springs' impulse is what the clamp does to the arm; the arm exerts the opposite.
        self._publish(-force / h)

    def _substeps_numpy(self, want, substeps, dt):
        """The sub-steps in numpy: ``substeps`` pymunk steps of ``dt`` under the servo (the module docstring's law)
        for commanded joint velocities ``want`` (rad/s, (B, 2)); returns the held springs' impulses summed over
        them, in ``_springs``' order. The reference the C loop (``_servo.c``) is checked against bit for bit.
        """
        v = self.values
        # The hot loop runs substeps times over the whole batch: the bodies' angular velocities read and their
        # torques written by pymunk's batch calls, one C call each for all trials, the servo law in numpy on
        # (B, 2) views (element-wise IEEE arithmetic in the order of the per-trial formula: the same numbers bit
        # for bit as a per-trial loop, without its Python calls), into arrays made once per step.
        gain, cap = v["servo_gain"][:, None], v["torque_limit"][:, None]
        floor, order, regular = -cap, self._order, self._regular
        speeds, torques = pymunk.batch.Buffer(), pymunk.batch.Buffer()
        torque = np.zeros(self._bodies)  # every body the batch call walks (the space's static one too) gets one
        torques.set_float_buf(torque)
        arms = 2 * self.batch_size
        joint = torque[:arms].reshape(-1, 2) if regular else np.zeros((self.batch_size, 2))  # (upper, forearm) each
        relative, tau = np.empty((self.batch_size, 2)), np.empty((self.batch_size, 2))
        springs, get_impulse = self._springs, chipmunk.cpConstraintGetImpulse
        impulses = np.zeros(len(springs))
        get_bodies, set_bodies, angular, torque_field = (pymunk.batch.get_space_bodies, pymunk.batch.set_space_bodies,
                                                         BodyFields.ANGULAR_VELOCITY, BodyFields.TORQUE)
        space, count = self.space, len(springs)
        for _ in range(substeps):
            speeds.clear()
            get_bodies(space, angular, speeds)
            speed = np.frombuffer(speeds.float_buf())
            speed = (speed[:arms] if regular else speed[order]).reshape(-1, 2)
            # shoulder: want - w_upper; elbow: want - (w_forearm - w_upper); then clip(K e, +-limit)
            relative[:, 0] = speed[:, 0]
            np.subtract(speed[:, 1], speed[:, 0], out=relative[:, 1])
            np.subtract(want, relative, out=tau)
            np.multiply(gain, tau, out=tau)
            np.maximum(tau, floor, out=tau)
            np.minimum(tau, cap, out=tau)
            np.subtract(tau[:, 0], tau[:, 1], out=joint[:, 0])  # the elbow motor pushes back on the upper arm
            joint[:, 1] = tau[:, 1]
            if not regular:
                torque[order] = joint.reshape(-1)
            set_bodies(space, torque_field, torques)
            space.step(dt)
            impulses += np.fromiter(map(get_impulse, springs), float, count)
        return impulses

    def _release(self, t):
        """Remove the load cell of every held trial whose ``release_time`` has come (the arm is free from now).

        Chipmunk removes a constraint by moving the space's last one into its place, which would reorder the
        OTHER trials' joints, and the solver's order changes its rounding. So the remaining constraints are put
        back in the order they were added, trial by trial: each trial's joints are solved in the order they would
        have in a space of its own, and its numbers do not depend on the other trials of the batch.
        """
        due = np.flatnonzero(np.isin(np.arange(self.batch_size), self._held)
                             & (t >= self.values["release_time"] - 1e-9))
        if not len(due):
            return
        for trial in due:
            self._cells[trial] = None
        self.space.remove(*self.space.constraints)
        self.space.add(*(joint for pins, cell in zip(self._pins, self._cells) for joint in (*pins, *(cell or ()))))
        self._held_springs()

    def _held_springs(self):
        """The held trials, and their load cells' springs (x, y per trial) as Chipmunk constraints and their addresses,
        in that order."""
        self._held = np.array([trial for trial, cell in enumerate(self._cells) if cell is not None], dtype=int)
        self._springs = [spring._constraint for trial in self._held for spring in self._cells[trial]]
        self._spring_addresses = np.array([address(spring) for spring in self._springs], dtype=np.uint64)

    def _publish(self, force):
        """Replace every output array from the bodies' current state (never mutate in place).

        The angles come from one batch read of the bodies' angles (pymunk's ``Body.angle``); each hand from
        Chipmunk's own cpBodyLocalToWorld on the forearm (``Body.local_to_world`` without its Python wrapper), so
        the numbers are the ones those calls give.
        """
        angles = pymunk.batch.Buffer()
        pymunk.batch.get_space_bodies(self.space, BodyFields.ANGLE, angles)
        angle = np.frombuffer(angles.float_buf())[self._order].reshape(-1, 2)  # (upper, forearm) per trial
        to_world, tip = chipmunk.cpBodyLocalToWorld, (FOREARM / 2, 0.0)
        hands = np.array([(hand.x, hand.y) for hand in (to_world(forearm._body, tip) for _, forearm in self._arms)]
                         ).reshape(-1, 2)
        self.values.update(q_shoulder=np.degrees(angle[:, 0]), q_elbow=np.degrees(angle[:, 1] - angle[:, 0]),
                           hand_x=hands[:, 0], hand_y=hands[:, 1], force_x=force[:, 0], force_y=force[:, 1])

    def terminate_hook(self):
        """Drop the pymunk space and its arms."""
        self._arms, self._cells, self._pins = [], [], []
        self.space = None

