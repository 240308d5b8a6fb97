"""The screen over the rubber arm: the image the participant sees, with the arm or without it as the scene says.

A lab hides the rubber arm for part of a trial (the lights go off while the participant points, a screen is
put over it): the seen image is then the scene without the arm. The screen takes two drawings of the same
scene, ``image`` with the rubber arm and ``ball_image`` without it (the ball alone, as a camera whose
``arm_visible`` is false draws it), and passes on the first while ``arm_visible`` is 1, the second while it
is 0 (the stimulus generator's schedule, ``rhi.components.stimulus``). It draws nothing itself.
"""
from __future__ import annotations

import numpy as np

from .component import Component
from .variables import Variable


class Screen(Component):
    """``image`` where ``arm_visible`` is 1, else ``ball_image``, per trial."""

    def __init__(self, name: str = "screen", resolution: int = 64):
        self.resolution = int(resolution)
        side = (self.resolution, self.resolution)
        image = dict(type="Array", shape=side, element="float32", unit="1", min=0.0, max=1.0)
        super().__init__(name, [
            Variable("image", "input", start=None, description="the scene with the rubber arm", **image),
            Variable("ball_image", "input", start=None, description="the same scene without the rubber arm", **image),
            Variable("arm_visible", "input", start=1.0, unit="1", description="1: the rubber arm is in view, 0: not"),
            Variable("seen", "output", start=None, depends_on=("image", "ball_image", "arm_visible"),
                     description="the image seen: the scene with the arm while it is in view, else without", **image),
        ])

    def initialize(self):
        """Publish the first ``seen`` image."""
        self._show()

    def step(self, t, h):
        """Publish ``seen`` (B, res, res) for the current inputs (``t``, ``h`` unused: it follows its inputs)."""
        self._show()

    def _show(self):
        v = self.values
        if v.get("image") is None or v.get("ball_image") is None:
            return  # before the cameras' first images reach it
        visible = np.asarray(v["arm_visible"]) > 0.5
        v["seen"] = np.where(visible[:, None, None], v["image"], v["ball_image"]).astype(np.float32, copy=False)
