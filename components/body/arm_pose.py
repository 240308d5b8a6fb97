"""Arm poses as ports: a still arm posed by its joint angles (a reach goal), and a body's joints as one pose.

- :class:`PosedArm`: parameters ``shoulder``, ``elbow`` (deg, per trial) -> ``pose`` (deg) and ``hand`` (m, the
  forward kinematics). It does not move: its outputs are computed once, at initialization. Seen by a camera,
  it is the released agent's attractor image, "the real arm set to the goal pose" (docs/reach.md).
- :class:`JointPose`: inputs ``q_shoulder``, ``q_elbow`` (deg; a body's outputs, two Reals by the body FMU
  contract) -> ``pose`` (deg), the one array a camera's ``arm_pose`` takes; direct feedthrough.
"""
from __future__ import annotations

import numpy as np

from .kinematics import REST_HAND, REST_POSE, forward
from ..component import Component, ComponentError
from ..variables import Variable


class PosedArm(Component):
    """A still arm at the joint angles (shoulder, elbow) its parameters give; outputs pose (deg) and hand (m)."""

    def __init__(self, name: str = "goal"):
        super().__init__(name, [
            Variable("shoulder", "parameter", start=REST_POSE[0], unit="deg",
                     description="shoulder angle: upper arm from +x"),
            Variable("elbow", "parameter", start=REST_POSE[1], unit="deg", min=-180.0, max=0.0,
                     description="elbow angle: forearm relative to upper arm (elbow-outward branch)"),
            Variable("pose", "output", "Array", shape=(2,), start=REST_POSE, unit="deg", depends_on=(),
                     description="the arm's joint angles: shoulder (from +x), elbow (relative)"),
            Variable("hand", "output", "Array", shape=(2,), start=REST_HAND, unit="m", depends_on=(),
                     description="the arm's hand position (x, y)"),
        ])

    def publish_initial(self):
        """Pose the arm as soon as the parameters are in: components earlier in the step order read it."""
        self.initialize()

    def initialize(self):
        """Publish ``pose`` (B, 2) deg and ``hand`` (B, 2) m of the parameters; ComponentError if one is not finite."""
        pose = np.stack([self.values["shoulder"], self.values["elbow"]], axis=1).astype(np.float64)
        if not np.all(np.isfinite(pose)):
            raise ComponentError(f"{self.name}.shoulder/elbow must be finite, got {pose.tolist()}")
        self.values["pose"] = pose
        self.values["hand"] = np.stack(forward(pose[:, 0], pose[:, 1]), axis=1)

    def step(self, t, h):
        """The arm does not move: its output arrays stay as they are (never mutated)."""


class JointPose(Component):
    """Two joint angles in, one pose array out (direct feedthrough)."""

    def __init__(self, name: str = "arm_pose"):
        super().__init__(name, [
            Variable("q_shoulder", "input", start=REST_POSE[0], unit="deg", description="shoulder angle"),
            Variable("q_elbow", "input", start=REST_POSE[1], unit="deg", description="elbow angle"),
            Variable("pose", "output", "Array", shape=(2,), start=REST_POSE, unit="deg",
                     depends_on=("q_shoulder", "q_elbow"), description="(shoulder, elbow)"),
        ])

    def initialize(self):
        """Publish ``pose`` of the inputs as set, as a step does."""
        self.step(0.0, 0.0)

    def step(self, t, h):
        """Publish ``pose`` (B, 2) deg: (q_shoulder, q_elbow) of the current inputs.

        Parameters
        ----------
        t, h : float
            The step's start and size, s (unused: the outputs follow the current inputs).
        """
        self.values["pose"] = np.stack([self.values["q_shoulder"], self.values["q_elbow"]], axis=1).astype(np.float64)
