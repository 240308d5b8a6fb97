"""The moving rubber hand's body side: the participant's own slow periodic movement, and a rubber arm that
mirrors the real arm with a visuomotor delay (docs/phenomena.md, "Moving rubber hand").

- :class:`Movement`: the commanded joint velocity of q(t) = q0 + A sin(2 pi t / T) at the shoulder (the elbow
  still), as the mean velocity over each step, so that a perfect servo lands on the sine at every step's end.
- :class:`MirroredArm`: the rubber arm's pose is its rest pose plus the real arm's displacement from rest
  ``delay`` seconds earlier (the real arm at rest before the run begins); ``delay`` is a whole number of steps.
"""
from __future__ import annotations

import math

import numpy as np

from .kinematics import REST_POSE, forward
from ..component import Component, ComponentError
from ..variables import Variable


def periodic_step_velocity(t, h, amplitude, period):
    """The mean velocity (deg/s) of q(t) = A sin(2 pi t / T) over [t, t + h]: (q(t + h) - q(t)) / h.

    The prescribed movement (a sine of amplitude A deg and period T s); amplitude, period: (B,).
    """
    omega = 2.0 * math.pi / period
    return amplitude * (np.sin(omega * (t + h)) - np.sin(omega * t)) / h


class Movement(Component):
    """The participant's own movement: outputs the commanded (shoulder, elbow) velocity, deg/s."""

    def __init__(self, name: str = "movement"):
        super().__init__(name, [
            Variable("amplitude", "parameter", start=5.0, unit="deg", min=0.0,
                     description="A: the shoulder's excursion from rest"),
            Variable("period", "parameter", start=4.0, unit="s", min=1e-3, description="T: the movement's period"),
            Variable("u_shoulder", "output", start=0.0, unit="deg/s", depends_on=(),
                     description="commanded shoulder velocity over the coming step"),
            Variable("u_elbow", "output", start=0.0, unit="deg/s", depends_on=(),
                     description="commanded elbow velocity (0: the elbow is still)"),
        ])

    def step(self, t, h):
        """The velocity for the step [t, t + h]: the body steps after this component, over the same step."""
        self.values["u_shoulder"] = periodic_step_velocity(t, h, self.values["amplitude"], self.values["period"])
        self.values["u_elbow"] = np.zeros(self.batch_size)


class MirroredArm(Component):
    """A rubber arm at ``rest`` that repeats the real arm's displacement ``delay`` seconds later."""

    def __init__(self, name: str = "rubber_arm", step_size: float = 0.02):
        self.step_size = step_size
        super().__init__(name, [
            Variable("delay", "parameter", start=0.0, unit="s", min=0.0, description="visuomotor delay"),
            Variable("rest_shoulder", "parameter", start=REST_POSE[0], unit="deg", description="rubber arm at rest"),
            Variable("rest_elbow", "parameter", start=REST_POSE[1], unit="deg", description="rubber arm at rest"),
            Variable("q_shoulder", "input", start=REST_POSE[0], unit="deg", description="the real arm's shoulder"),
            Variable("q_elbow", "input", start=REST_POSE[1], unit="deg", description="the real arm's elbow"),
            Variable("pose", "output", "Array", shape=(2,), start=REST_POSE, unit="deg", depends_on=(),
                     description="the rubber arm's joint angles"),
            Variable("hand", "output", "Array", shape=(2,), start=(-0.30, 0.50), unit="m", depends_on=(),
                     description="the rubber hand (x, y)"),
        ])

    def publish_initial(self):
        """Publish the rubber arm at rest as soon as the parameters are in (:meth:`initialize`)."""
        self.initialize()

    def initialize(self):
        """Start the history with the real arm at rest, and publish the rubber arm at rest: ``pose`` (B, 2) deg,
        ``hand`` (B, 2) m. ComponentError if ``delay`` is not a whole number of steps.
        """
        lag = self.values["delay"] / self.step_size
        if np.any(np.abs(lag - np.round(lag)) > 1e-6):
            raise ComponentError(f"{self.name}.delay = {self.values['delay'].tolist()} s must be a whole number of "
                                 f"{self.step_size} s steps")
        self._lag = np.round(lag).astype(int)
        self._history = [np.zeros((self.batch_size, 2))]  # displacement from rest, one entry per step seen
        self._publish(np.zeros((self.batch_size, 2)))

    def _publish(self, displacement):
        rest = np.stack([self.values["rest_shoulder"], self.values["rest_elbow"]], axis=1)
        pose = rest + displacement
        self.values["pose"] = pose
        self.values["hand"] = np.stack(forward(pose[:, 0], pose[:, 1]), axis=1)

    def step(self, t, h):
        """The real arm as sensed now (the body's outputs of the step before) joins the history; the rubber arm
        shows the entry ``delay`` older."""
        real = np.stack([self.values["q_shoulder"], self.values["q_elbow"]], axis=1) - np.array(REST_POSE)
        self._history.append(real)
        newest = len(self._history) - 1
        shown = np.stack([self._history[max(0, newest - lag)][trial] for trial, lag in enumerate(self._lag)])
        self._publish(shown)
