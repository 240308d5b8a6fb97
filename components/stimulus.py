"""The stimulus generator: visual touches of the rubber hand and tactile touches of the real hand.

The stroking happens in blocks [start, end] s (``blocks``, one row each; by default one block
[0, inf]): within a block a visual event (the ball touches the rubber hand) happens every
``period`` seconds, at t = start + period, start + 2 period, ... up to ``end``; so by default at
t = period, 2 period, ... Visual event k (counted over the whole trial) is followed by a tactile
event on the real hand after a delay drawn from U[delay_min, delay_max) (synchronous 0..0.1 s,
asynchronous 0..1 s; delay_min == delay_max is a fixed delay), from a numpy Generator seeded per
trial; with ``touch`` false (vision only) there is no tactile event, the delays are drawn all the
same. An event is observed on the first communication step that ends at or after its time; the
outputs hold the time of the last observed event of each kind (-inf before any). No visual event
(and so no tactile one) happens after ``stop_time`` (inf: stroking never stops); the ball then rests on
the target.

The ball strokes: during the last ``stroke_duration`` seconds before each visual event (inf: the
whole period) it approaches the target (the rubber hand) in a straight line from ``ball_distance``
metres forward of it (+y), linearly, and reaches it at the event; between strokes (a pause within
the period, between blocks, after the last block) it rests where the last touch left it, and before
the first stroke it waits ``ball_distance`` forward of the target. Until ``stop_time`` the ball heads
for the blocks' next event even if ``stop_time`` cancels it (as the stimulus always did).

The schedule (the visual events, the ball's stroke) is a function of the trial's schedule parameters alone, so
it is computed once per distinct schedule of the batch (a cohort's cell has one) and gathered to its trials;
only the delays, and so the tactile events, are each trial's own.

The scene's other schedule is the rubber arm's visibility: ``arm_in_view`` (false: no rubber arm in this
trial at all) and ``hidden`` intervals [start, end) s in which it is out of view (a reading in the dark, a
screen); the output ``arm_visible`` is 1 while it is in view, else 0, at the step's end. Both tables
(``blocks``, ``hidden``) hold as many rows as the constructor is given (structural, as a camera's
resolution), so a schedule has any number of them; unused rows are NaN.
"""
from __future__ import annotations

import numpy as np

from .component import Component, ComponentError
from .variables import Variable

TOLERANCE = 1e-9  # s: an event at 2.0 is observed at a step ending at 2.0 - 1e-12 (float ticks)
CHUNK = 64        # delays drawn per trial at a time


def interval_rows(intervals, rows: int | None = None, empty=None) -> np.ndarray:
    """``intervals`` ([[start_s, end_s], ...]) as a table parameter's value, (rows, 2) s, unused rows NaN; ``rows``
    defaults to as many as needed (at least one); ``empty`` is the table of no interval (default: all NaN)."""
    table = np.asarray(intervals, dtype=np.float64).reshape(-1, 2)
    if len(table) == 0 and empty is not None:
        table = np.asarray(empty, dtype=np.float64).reshape(-1, 2)
    rows = max(len(table), 1) if rows is None else rows
    if len(table) > rows:
        raise ComponentError(f"stimulus: {len(table)} intervals do not fit in a table of {rows} rows")
    return np.vstack([table, np.full((rows - len(table), 2), np.nan)])


def block_rows(blocks, rows: int | None = None) -> np.ndarray:
    """``blocks`` ([[start_s, end_s], ...]; empty: one block [0, inf]) as the ``blocks`` parameter's value,
    (rows, 2) s, unused rows NaN (:func:`interval_rows`)."""
    return interval_rows(blocks, rows, empty=[[0.0, np.inf]])


def check_intervals(name: str, table: np.ndarray, least: int) -> None:
    """ComponentError unless ``table`` (rows, 2) s holds at least ``least`` [start, end] rows first, then only
    NaN rows, with 0 <= start < end (end may be inf), each at or after the previous end."""
    used = ~np.isnan(table[:, 0])
    count = int(used.sum())
    starts, ends = table[:count, 0], table[:count, 1]
    if (not used[:count].all() or np.isnan(table[count:]).sum() != 2 * (len(table) - count) or count < least
            or np.isnan(ends).any() or np.any(starts < 0) or np.isinf(starts).any() or np.any(~(starts < ends))
            or np.any(starts[1:] < ends[:-1])):
        raise ComponentError(f"{name} = {table[:max(count, 1)].tolist()} must be [start, end] rows with "
                             "0 <= start < end, each at or after the previous end")


class Stimulus(Component):
    """Event times and ball position for B trials."""

    def __init__(self, name: str = "stimulus", blocks: int = 1, hidden: int = 1):
        self.block_count, self.hidden_count = int(blocks), int(hidden)
        if self.block_count < 1 or self.hidden_count < 1:
            raise ComponentError(f"{name}: the blocks and hidden tables need at least one row each")
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
            Variable("stroke_duration", "parameter", start=np.inf, min=0.0, unit="s",
                     description="the ball moves onto the target during this long before each touch (inf: the "
                                 "whole period)"),
            Variable("touch", "parameter", "Boolean", start=True, unit="1",
                     description="tactile events follow the visual ones (false: vision only)"),
            Variable("blocks", "parameter", "Array", shape=(self.block_count, 2), start=block_rows([], self.block_count),
                     unit="s", description="stroking blocks [start, end], in order, unused rows NaN (default: [0, inf])"),
            Variable("hidden", "parameter", "Array", shape=(self.hidden_count, 2),
                     start=interval_rows([], self.hidden_count), unit="s",
                     description="intervals [start, end) in which the rubber arm is out of view, in order, unused "
                                 "rows NaN (default: none)"),
            Variable("arm_in_view", "parameter", "Boolean", start=True, unit="1",
                     description="a rubber arm is in view in this trial (false: none at any time)"),
            Variable("arm_visible", "output", start=1.0, unit="1", depends_on=(),
                     description="1 while the rubber arm is in view, else 0"),
        ])

    def check_parameters(self):
        """ComponentError if ``delay_max`` is below ``delay_min`` in any trial, a ``stroke_duration`` is 0, or a
        trial's ``blocks`` or ``hidden`` intervals are not in order (each start >= 0 and below its end, at or after
        the previous end, the used rows first; at least one block)."""
        v = self.values
        if np.any(v["delay_max"] < v["delay_min"]):
            raise ComponentError(f"{self.name}.delay_max = {v['delay_max'].tolist()} is below delay_min = "
                                 f"{v['delay_min'].tolist()}")
        if np.any(v["stroke_duration"] <= 0):
            raise ComponentError(f"{self.name}.stroke_duration = {v['stroke_duration'].tolist()} must be positive")
        for trial in range(self.batch_size):
            check_intervals(f"{self.name}.blocks of trial {trial}", v["blocks"][trial], 1)
            check_intervals(f"{self.name}.hidden of trial {trial}", v["hidden"][trial], 0)

    def initialize(self):
        """Seed each trial's delay generator with its ``seed`` and publish the outputs at the start time."""
        self.check_parameters()
        v = self.values
        self._generators = [np.random.default_rng(int(seed)) for seed in v["seed"]]
        self._delays = np.empty((self.batch_size, 0))
        # the batch's distinct schedules: each one's first trial, and each trial's schedule
        rows = np.concatenate([v["period"][:, None], v["blocks"].reshape(self.batch_size, -1), v["stop_time"][:, None],
                               v["stroke_duration"][:, None], v["ball_distance"][:, None]], axis=1)
        _, self._schedules, self._schedule_of = np.unique(np.ascontiguousarray(rows).view(
            np.dtype((np.void, rows.shape[1] * 8))).ravel(), return_index=True, return_inverse=True)
        self._schedule_of = self._schedule_of.reshape(-1)
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
        """Set the outputs for time ``now`` (s) from the schedule (:func:`schedule`) and the ball's stroke."""
        v = self.values
        first, of = self._schedules, self._schedule_of  # the schedule's work on its distinct rows, then gathered
        period, stop_time = v["period"][first], v["stop_time"][first]
        counts, sizes, starts, visual, next_event = schedule(now, period, v["blocks"][first], stop_time)
        total = counts.sum(axis=1)
        latest = int(total.max())
        tactile = event_times(latest, period, starts, sizes)[of] + self.delays(latest)
        index = np.arange(1, latest + 1)
        observed = (tactile <= now + TOLERANCE) & (index[None, :] <= total[of, None]) & v["touch"][:, None]
        v["visual_time"] = visual[of]
        v["tactile_time"] = np.where(observed, tactile, -np.inf).max(axis=1, initial=-np.inf)
        ball = np.array(v["target"], dtype=np.float64, copy=True)
        stopped = now + TOLERANCE > stop_time
        ball[:, 1] += (v["ball_distance"][first] * stroke_position(now, period, v["stroke_duration"][first], visual,
                                                                   next_event, stopped))[of]
        v["ball"] = ball
        v["arm_visible"] = arm_visible(now, v["arm_in_view"], v["hidden"])


def arm_visible(now: float, in_view, hidden) -> np.ndarray:
    """Whether the rubber arm is in view at ``now``, (B,) 1 or 0: in view in the trial (``in_view``, (B,) bool)
    and ``now`` in none of its ``hidden`` intervals [start, end) ((B, H, 2) s, unused rows NaN; an event at a
    boundary within TOLERANCE of the step's end counts as reached)."""
    inside = (hidden[:, :, 0] <= now + TOLERANCE) & (now + TOLERANCE < hidden[:, :, 1])  # NaN rows: False
    return (np.asarray(in_view, bool) & ~inside.any(axis=1)).astype(np.float64)


def schedule(now: float, period, blocks, stop_time):
    """The visual events of a block schedule up to ``now``: events at start + k period, k >= 1, within each block
    [start, end] and at or before ``stop_time`` (docs/configuration.md, "Stimulation schedules").

    Parameters
    ----------
    now : float
        The time, s.
    period : (B,) s
    blocks : (B, rows, 2) s, unused rows NaN
    stop_time : (B,) s

    Returns
    -------
    counts : (B, n) events observed by ``now`` in each of the batch's n used block columns.
    sizes : (B, n) events of each block in all (inf for an endless one; 0 for an unused row).
    starts : (B, n) s, the blocks' starts (0 for an unused row).
    visual : (B,) s, the last observed event's time (-inf before any).
    next_event : (B,) s, the next event's time by the blocks alone, not ``stop_time`` (inf when none is left): where
        the ball is heading until ``stop_time`` (:func:`stroke_position`).
    """
    used = int((~np.isnan(blocks[:, :, 0])).sum(axis=1).max())
    rows = blocks[:, :used]
    valid = ~np.isnan(rows[:, :, 0])
    starts = np.where(valid, rows[:, :, 0], 0.0)
    step = period[:, None]

    def size(ends):  # events of each block up to ``ends``
        return np.where(valid & (ends >= starts), np.floor((ends - starts + TOLERANCE) / step), 0.0)
    sizes = size(np.where(valid, np.minimum(rows[:, :, 1], stop_time[:, None]), -np.inf))
    counts = np.clip(np.floor((now - starts + TOLERANCE) / step), 0.0, sizes).astype(np.int64)
    column = np.arange(used)
    last = np.where(counts > 0, column, -1).max(axis=1)  # the last block with an event so far
    take = np.maximum(last, 0)[:, None]
    visual = np.where(last >= 0, np.take_along_axis(starts, take, 1)[:, 0]
                      + np.take_along_axis(counts, take, 1)[:, 0] * period, -np.inf)
    left = counts < size(np.where(valid, rows[:, :, 1], -np.inf))
    first = np.where(left, column, used).min(axis=1)  # the first block with an event to come
    take = np.minimum(first, used - 1)[:, None]
    next_event = np.where(first < used, np.take_along_axis(starts, take, 1)[:, 0]
                          + (np.take_along_axis(counts, take, 1)[:, 0] + 1) * period, np.inf)
    return counts, sizes, starts, visual, next_event


def event_times(count: int, period, starts, sizes) -> np.ndarray:
    """The times (B, count) s of the first ``count`` visual events of each trial's schedule, in order (events
    beyond a trial's schedule get times past its last block's end; the caller masks them)."""
    if count == 0:
        return np.empty((len(period), 0))
    index = np.arange(count, dtype=np.float64)[None, :, None]  # 0-based event number over the whole trial
    before = np.concatenate([np.zeros((len(sizes), 1)), np.cumsum(sizes, axis=1)[:, :-1]], axis=1)  # earlier blocks'
    block = np.maximum((before[:, None, :] <= index).sum(axis=2) - 1, 0)  # (B, count): the block of each event
    within = index[:, :, 0] - np.take_along_axis(before, block, 1) + 1  # 1-based number within its block
    return np.take_along_axis(starts, block, 1) + within * period[:, None]


def stroke_position(now: float, period, stroke_duration, visual, next_event, stopped) -> np.ndarray:
    """How far along its path the ball is at ``now``, (B,), 1 = ``ball_distance`` forward of the target, 0 = on it:
    linearly from 1 to 0 over the ``stroke_duration`` (at most the period) before each visual event, 0 at an
    event and until the next stroke begins, 1 before the first stroke, and 0 once ``stopped`` (past ``stop_time``,
    (B,) bool: the ball rests on the target; the ball's stroke of the module docstring).
    """
    duration = np.minimum(stroke_duration, period)
    remaining = next_event - now
    at_event = np.isfinite(visual) & (np.abs(visual - now) <= TOLERANCE)
    begun = remaining <= duration + TOLERANCE
    with np.errstate(invalid="ignore"):
        moving = np.clip(remaining / duration, 0.0, 1.0)
    waiting = np.where(np.isfinite(visual), 0.0, 1.0)
    return np.where(at_event | stopped, 0.0, np.where(begun, moving, waiting))
