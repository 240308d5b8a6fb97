"""The stimulus generator: visual touches of the rubber hand and tactile touches of the real hand.

A visual event (the ball touches the rubber hand) happens every ``period`` seconds, at
t = period, 2 period, ...; visual event k is followed by a tactile event on the real hand
after a delay drawn from U[delay_min, delay_max) (synchronous 0..0.1 s, asynchronous
0..1 s; delay_min == delay_max is a fixed delay), from a numpy Generator seeded per trial.
An event is observed on the first communication step that ends at or after its time; the
outputs hold the time of the last observed event of each kind (-inf before any). No visual
event (and so no tactile one) happens after ``stop_time`` (inf: stroking never stops); the
ball then rests where the last touch left it.

The ball approaches the target (the rubber hand) in a straight line from ``ball_distance``
metres forward of it (+y), linearly over each period, and reaches it at the visual event.
"""
from __future__ import annotations

import numpy as np

from components.component import Component, ComponentError
from components.variables import Variable

TOLERANCE = 1e-9  # s: an event at 2.0 is observed at a step ending at 2.0 - 1e-12 (float ticks)
CHUNK = 64        # delays drawn per trial at a time


class Stimulus(Component):
    """Event times and ball position for B trials."""

    def __init__(self, name: str = "stimulus"):
        super().__init__(name, [
            Variable("period", "parameter", start=2.0, min=1e-3, unit="s", description="time between visual events"),
            Variable("delay_min", "parameter", start=0.0, min=0.0, unit="s",
                     description="smallest visuo-tactile delay (sync 0, async 0)"),
            Variable("delay_max", "parameter", start=0.1, min=0.0, unit="s",
                     description="delays are U[delay_min, delay_max) (sync 0.1, async 1); equal = fixed"),
            Variable("seed", "parameter", "Integer", start=0, min=0, unit="1", description="per-trial seed"),
            Variable("ball_distance", "parameter", start=0.25, min=0.0, unit="m",
                     description="how far forward of the target the ball starts each period"),
            Variable("stop_time", "parameter", start=np.inf, min=0.0, unit="s",
                     description="no touch after this time (inf: the stroking never stops)"),
            Variable("target", "input", "Array", shape=(2,), start=(-0.30, 0.50), unit="m",
                     description="where the ball touches: the rubber hand (x, y)"),
            Variable("visual_time", "output", start=-np.inf, unit="s", depends_on=(),
                     description="time of the last observed visual event (-inf before any)"),
            Variable("tactile_time", "output", start=-np.inf, unit="s", depends_on=(),
                     description="time of the last observed tactile event (-inf before any)"),
            Variable("ball", "output", "Array", shape=(2,), start=None, unit="m", depends_on=("target",),
                     description="ball position (x, y)"),
        ])

    def check_parameters(self):
        """ComponentError if ``delay_max`` is below ``delay_min`` in any trial."""
        v = self.values
        if np.any(v["delay_max"] < v["delay_min"]):
            raise ComponentError(f"{self.name}.delay_max = {v['delay_max'].tolist()} is below delay_min = "
                                 f"{v['delay_min'].tolist()}")

    def initialize(self):
        """Seed each trial's delay generator with its ``seed`` and publish the outputs at the start time."""
        self.check_parameters()
        v = self.values
        self._generators = [np.random.default_rng(int(seed)) for seed in v["seed"]]
        self._delays = np.empty((self.batch_size, 0))
        self._publish(self.start_time)

    def step(self, t, h):
        """Publish the events observed by the step's end, ``t + h``: ``visual_time``, ``tactile_time`` (B,) s, and
        ``ball`` (B, 2) m.

        Parameters
        ----------
        t, h : float
            The step's start and size, s.
        """
        self._publish(t + h)

    def delays(self, count: int) -> np.ndarray:
        """The first ``count`` visuo-tactile delays of every trial, (B, count) s, drawn as needed."""
        while self._delays.shape[1] < count:
            low, high = self.values["delay_min"], self.values["delay_max"]
            fresh = np.stack([g.uniform(lo, hi, CHUNK) for g, lo, hi in zip(self._generators, low, high)])
            self._delays = np.concatenate([self._delays, fresh], axis=1)
        return self._delays[:, :count]

    def _publish(self, now: float):
        period = self.values["period"]
        visual_count = np.floor((now + TOLERANCE) / period).astype(np.int64)  # events at period * k, k >= 1
        stop = self.values["stop_time"]
        stopped = np.isfinite(stop) & (now + TOLERANCE > stop)
        if stopped.any():  # the last touch at or before stop_time (the paper's stop_time = inf never enters)
            last = np.floor((np.where(np.isfinite(stop), stop, 0.0) + TOLERANCE) / period).astype(np.int64)
            visual_count = np.where(stopped, np.minimum(visual_count, last), visual_count)
        latest = int(visual_count.max())
        k = np.arange(1, latest + 1)
        tactile = k[None, :] * period[:, None] + self.delays(latest)
        observed = (tactile <= now + TOLERANCE) & (k[None, :] <= visual_count[:, None])
        self.values["visual_time"] = np.where(visual_count > 0, visual_count * period, -np.inf)
        self.values["tactile_time"] = np.where(observed, tactile, -np.inf).max(axis=1, initial=-np.inf)
        remaining = (visual_count + 1) * period - now  # until the next visual event
        at_event = (visual_count > 0) & (np.abs(visual_count * period - now) <= TOLERANCE)
        remaining = np.where(at_event | (stopped & (visual_count * period <= now)), 0.0, remaining)
        ball = np.array(self.values["target"], dtype=np.float64, copy=True)
        ball[:, 1] += self.values["ball_distance"] * np.clip(remaining / period, 0.0, 1.0)
        self.values["ball"] = ball
