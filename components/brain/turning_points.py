"""Seen and felt events of a moving arm: the turning points of its movement (the moving rubber hand).

With no touch, what a seen and a felt arm share in time is their movement. The paper's causal inference
(eqs. 8-9) weighs the delay between a seen and a felt event; here the events are the turning points of the
shoulder's movement, where its velocity changes sign: the seen arm's (the rubber arm's pose) and the felt
arm's (the sensed joint angle s_p). The outputs take the place of the stimulus's ``visual_time`` and
``tactile_time`` at the brain's inputs: the felt turning point plays the felt touch's part.

A turning point is observed on the step whose sample shows the movement reversed: the time given is that of
the extreme sample (one step earlier), for the seen and the felt arm alike, so their difference is exact.
"""
from __future__ import annotations

import numpy as np

from ..component import Component
from ..variables import Variable

STILL = 1e-9  # deg: a change smaller than this is no movement (it sets no direction)


def turned(previous_direction, change):
    """(turned (B,), new direction (B,)): a reversal where the change opposes the last direction of movement.

    Directions are +1, -1, or 0 (not moved yet); a change under STILL keeps the direction.

    Parameters
    ----------
    previous_direction : ndarray, (B,)
        +1, -1 or 0.
    change : ndarray, (B,)
        This step's change of the angle, deg.

    Returns
    -------
    turned : ndarray of bool, (B,)
    direction : ndarray, (B,)
        The direction after this step.
    """
    moving = np.abs(change) > STILL
    direction = np.where(moving, np.sign(change), previous_direction)
    return moving & (previous_direction != 0) & (direction != previous_direction), direction


class TurningPoints(Component):
    """The last turning points of the seen and the felt shoulder: seen_pose, q_shoulder in; event times out.

    Parameters
    ----------
    name : str
        The instance name in a system.
    """

    def __init__(self, name: str = "turning_points"):
        super().__init__(name, [
            Variable("seen_pose", "input", "Array", shape=(2,), start=(0.0, 0.0), unit="deg",
                     description="the seen arm's joint angles"),
            Variable("q_shoulder", "input", start=0.0, unit="deg", description="the felt shoulder angle s_p"),
            Variable("visual_time", "output", start=-np.inf, unit="s", depends_on=(),
                     description="time of the seen arm's last turning point (-inf before any)"),
            Variable("tactile_time", "output", start=-np.inf, unit="s", depends_on=(),
                     description="time of the felt arm's last turning point (-inf before any)"),
        ])

    def initialize(self):
        """No turning point seen or felt yet: the last positions, no direction, both event times -inf."""
        batch = self.batch_size
        self._last = {"seen": np.array(self.values["seen_pose"][:, 0], float), "felt": np.array(self.values["q_shoulder"], float)}
        self._direction = {"seen": np.zeros(batch), "felt": np.zeros(batch)}
        self.values["visual_time"], self.values["tactile_time"] = np.full(batch, -np.inf), np.full(batch, -np.inf)

    def step(self, t, h):
        """A seen (felt) turning point's time becomes the visual (tactile) event time."""
        for key, now, output in (("seen", self.values["seen_pose"][:, 0], "visual_time"),
                                 ("felt", self.values["q_shoulder"], "tactile_time")):
            now = np.array(now, dtype=float)
            reversal, self._direction[key] = turned(self._direction[key], now - self._last[key])
            self._last[key] = now
            if reversal.any():
                self.values[output] = np.where(reversal, t - h, self.values[output])
