"""The rubber (virtual) arm: a kinematic arm on the real shoulder, posed by inverse kinematics.

Its hand sits at REST_HAND + (offset_x, offset_y): Left offset_x = -0.15 m, Center 0,
Right +0.15 m (docs/design.md); any other offset is allowed for distance studies. It does not
move within a trial, so its outputs are computed once, at initialization.
"""
from __future__ import annotations

import numpy as np

from .kinematics import REST_HAND, REST_POSE, inverse
from ..component import Component, ComponentError
from ..variables import Variable


class RubberArm(Component):
    """Parameters offset_x, offset_y (m, per trial); outputs pose (deg) and hand (m)."""

    def __init__(self, name: str = "rubber_arm"):
        super().__init__(name, [
            Variable("offset_x", "parameter", start=0.0, unit="m",
                     description="rubber hand x minus resting real hand x (left -0.15, right +0.15)"),
            Variable("offset_y", "parameter", start=0.0, unit="m",
                     description="rubber hand y minus resting real hand y"),
            Variable("pose", "output", "Array", shape=(2,), start=REST_POSE, unit="deg", depends_on=(),
                     description="rubber arm joint angles: shoulder (from +x), elbow (relative)"),
            Variable("hand", "output", "Array", shape=(2,), start=REST_HAND, unit="m", depends_on=(),
                     description="rubber hand position (x, y), where the ball touches"),
        ])

    def publish_initial(self):
        """Pose the arm as soon as the parameters are in: components earlier in the step order read it."""
        self.initialize()

    def check_parameters(self):
        """ComponentError if ``offset_x``, ``offset_y`` put the rubber hand out of the arm's reach."""
        self._pose()

    def initialize(self):
        """Publish ``hand`` (B, 2) m, REST_HAND plus the offsets, and ``pose`` (B, 2) deg by inverse kinematics."""
        self.values["pose"], self.values["hand"] = self._pose()

    def _pose(self):
        """The rubber arm's joint angles (B, 2) and hand (B, 2); a ComponentError if a hand is out of reach."""
        hand = np.stack([REST_HAND[0] + self.values["offset_x"], REST_HAND[1] + self.values["offset_y"]], axis=1)
        try:
            shoulder, elbow = inverse(hand[:, 0], hand[:, 1])
        except ComponentError as error:
            raise ComponentError(f"{self.name}.offset_x/offset_y = ({self.values['offset_x'].tolist()}, "
                                 f"{self.values['offset_y'].tolist()}) put the rubber hand out of reach: "
                                 f"{error}") from None
        return np.stack([shoulder, elbow], axis=1), hand

    def step(self, t, h):
        """The rubber arm does not move: its output arrays stay as they are (never mutated)."""
