"""A second body for the same contract: a purely kinematic arm (``rhi export-body --variant kinematic``).

Where :class:`~rhi.components.body.plant.ArmPlant` simulates masses, a velocity servo
and a compliant load cell in pymunk, this arm has no dynamics at all:

- free: the joints follow the command exactly, q(t + h) = q(t) + h * u;
- held: the joints do not move, and the hand force is the quasi-static limit of the
  pymunk plant's servo: joint torques tau = clip(K * u, +-limit) (u in rad/s)
  balanced at the clamped hand, F = J^-T tau, J the hand Jacobian in m/rad.

Swapping it for the pymunk plant changes only what the physics changes: the servo
lag and the tracking error in free mode, the transient and the load-cell
compliance in held mode.
"""
from __future__ import annotations

import math

import numpy as np

from .kinematics import forward, jacobian
from .plant import ArmPlant
from ..component import Component, StepFailure

# The contract's variables and the servo parameters, declared exactly as the pymunk plant declares them.
SHARED = ("u_shoulder", "u_elbow", "q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y",
          "held", "q0_shoulder", "q0_elbow", "servo_gain", "torque_limit")


def held_hand_force(shoulder_deg, elbow_deg, command_deg_s, servo_gain, torque_limit):
    """Force (N, shape (B, 2)) a clamped arm exerts at the hand when its servo pushes with zero speed.

    Statics: the joint torques tau = clip(K * u, +-limit) are balanced by the clamp,
    tau = J^T F, so F = J^-T tau with J = d(hand)/d(angles) in m/rad.
    """
    torque = np.clip(servo_gain[:, None] * np.radians(command_deg_s), -torque_limit[:, None],
                     torque_limit[:, None])
    per_radian = jacobian(shoulder_deg, elbow_deg) * (180.0 / math.pi)
    return np.linalg.solve(np.swapaxes(per_radian, -1, -2), torque[..., None])[..., 0]


class KinematicArm(Component):
    """A kinematic arm on the body contract: integrates the command when free; statics when held."""

    def __init__(self, name: str = "body"):
        declared = ArmPlant().variables
        super().__init__(name, [declared[n] for n in SHARED])

    def publish_initial(self):
        """The initial pose as soon as the parameters are in, as the pymunk plant publishes it."""
        self._publish(self.values["q0_shoulder"].copy(), self.values["q0_elbow"].copy(),
                      np.zeros((self.batch_size, 2)))

    def initialize(self):
        """Publish the initial pose (q0_shoulder, q0_elbow), deg, and zero force."""
        self._publish(self.values["q0_shoulder"].copy(), self.values["q0_elbow"].copy(),
                      np.zeros((self.batch_size, 2)))

    def step(self, t, h):
        """Free: the joints move by ``h`` times the command (deg). Held: they stay, and the hand force (N) is the
        servo's static push (:func:`held_hand_force`). StepFailure if the command is not finite.

        Parameters
        ----------
        t, h : float
            The step's start and size, s.
        """
        v = self.values
        command = np.stack([v["u_shoulder"], v["u_elbow"]], axis=1)
        if not np.all(np.isfinite(command)):
            raise StepFailure(f"{self.name}: commanded velocity is not finite: {command.tolist()}")
        held = v["held"]
        shoulder = np.where(held, v["q_shoulder"], v["q_shoulder"] + h * command[:, 0])
        elbow = np.where(held, v["q_elbow"], v["q_elbow"] + h * command[:, 1])
        force = held_hand_force(shoulder, elbow, command, v["servo_gain"], v["torque_limit"])
        self._publish(shoulder, elbow, np.where(held[:, None], force, 0.0))

    def _publish(self, shoulder, elbow, force):
        """Replace every output array (never mutate in place)."""
        hand_x, hand_y = forward(shoulder, elbow)
        self.values.update(q_shoulder=shoulder, q_elbow=elbow, hand_x=hand_x, hand_y=hand_y,
                           force_x=force[:, 0], force_y=force[:, 1])
