"""Stimulation schedules and probes: the checks of their configuration keys (docs/configuration.md,
"Stimulation schedules"), each refusal one line naming the key.

A stimulation (``[stimulations.NAME]``) strokes in ``blocks`` ([[start_s, end_s], ...], in order, not
overlapping; [] = one block over the whole trial) and with ``touch`` (false: vision only); the ball's
stroke lasts ``stimulus.stroke_duration`` of each ``stimulus.period``; ``rubber_arm.hidden_conditions``
names the conditions without a rubber arm in view; ``experiment.probe_times`` are the times at which
the drift is read besides the end of the trial. ``[readings]`` are events of the lab's own schedule: each
pauses the stroking for its ``duration`` (the blocks are cut around it, :func:`stroking_blocks`) and, with
``hide_arm``, takes the rubber arm out of view for it, as ``rubber_arm.hidden_times`` does at given times
(:func:`hidden_intervals`). Any number of blocks, readings and intervals.
"""
from __future__ import annotations

import math

from rhi.master.cosim import ConfigError


def trial_length(config: dict) -> float:
    """The trial's length, s: ``experiment.steps`` x ``experiment.step_size``."""
    return config["experiment"]["steps"] * config["experiment"]["step_size"]


def finite(value) -> bool:
    """Whether ``value`` is a finite int or float (not a Boolean)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_blocks(name: str, blocks, period: float, length: float) -> None:
    """``stimulations.NAME.blocks``: intervals as :func:`check_intervals` has them, each at least one ``period``
    long (else it holds no touch); else a ConfigError naming the key."""
    key = f"stimulations.{name}.blocks"
    check_intervals(key, blocks, length, "block ")
    for block in blocks:
        if block[1] - block[0] < period:
            raise ConfigError(f"{key}: block {block!r} is shorter than stimulus.period = {period:g} s, so it holds "
                              "no touch")


def check_intervals(key: str, intervals, length: float, noun: str = "") -> None:
    """``key``: a list of [start, end] pairs of finite seconds, 0 <= start < end, starting before the trial ends
    (``length``, experiment.steps x experiment.step_size), in order and not overlapping; else a ConfigError naming
    the key and the pair (``noun`` before it, e.g. ``"block "``)."""
    if not isinstance(intervals, list):
        raise ConfigError(f"{key} must be a list of [start_s, end_s] pairs, got {intervals!r}")
    previous_end = 0.0
    for pair in intervals:
        if not (isinstance(pair, list) and len(pair) == 2 and all(finite(v) for v in pair)):
            raise ConfigError(f"{key}: {pair!r} must be a pair [start_s, end_s] of finite numbers")
        start, end = pair
        if not 0 <= start < end:
            raise ConfigError(f"{key}: {noun}{pair!r} needs 0 <= start < end, s")
        if start < previous_end:
            raise ConfigError(f"{key}: {noun}{pair!r} overlaps the one before it, which ends at {previous_end:g} s "
                              "(in order, not overlapping)")
        if start >= length:
            raise ConfigError(f"{key}: {noun}{pair!r} starts at or after the trial's end, {length:g} s")
        previous_end = end


def check_readings(readings: dict, length: float) -> None:
    """``[readings]``: ``times`` finite, >= 0, strictly increasing and before the trial's end; ``duration`` finite
    and >= 0, each reading over before the next begins; ``hide_arm`` true or false; else a ConfigError naming
    the key."""
    times, duration, hide = readings["times"], readings["duration"], readings["hide_arm"]
    if not finite(duration) or duration < 0:
        raise ConfigError(f"readings.duration = {duration!r} must be a finite time >= 0, s")
    if not isinstance(hide, bool):
        raise ConfigError(f"readings.hide_arm = {hide!r} must be true or false")
    if not isinstance(times, list) or not all(finite(t) for t in times):
        raise ConfigError(f"readings.times = {times!r} must be a list of finite times, s")
    for time in times:
        if not 0 <= time < length:
            raise ConfigError(f"readings.times: {time:g} s is not within the trial, [0, {length:g}) s "
                              "(experiment.steps x experiment.step_size)")
    for earlier, later in zip(times, times[1:]):
        if later <= earlier:
            raise ConfigError(f"readings.times = {times!r} must be strictly increasing")
        if earlier + duration > later:
            raise ConfigError(f"readings: the reading at {earlier:g} s lasts {duration:g} s and overlaps the one "
                              f"at {later:g} s")


def reading_intervals(readings: dict) -> list[tuple[float, float]]:
    """The readings as [start, end) intervals, s (none when their duration is 0)."""
    duration = float(readings["duration"])
    return [(float(t), float(t) + duration) for t in readings["times"]] if duration > 0 else []


def stroking_blocks(blocks, readings: dict) -> tuple:
    """A stimulation's ``blocks`` with the readings cut out: ((start_s, end_s), ...), each block less the time of
    every reading within it; () when the stimulation strokes over the whole trial and no reading pauses it (the
    component's default block [0, inf]). A reading pauses the stroking: the next touch is one period after it
    ends (the stimulus generator's blocks)."""
    pauses = reading_intervals(readings)
    pieces = [(float(start), float(end)) for start, end in blocks] or ([(0.0, math.inf)] if pauses else [])
    for pause_start, pause_end in pauses:
        cut = []
        for start, end in pieces:
            if pause_end <= start or end <= pause_start:
                cut.append((start, end))
                continue
            if start < pause_start:
                cut.append((start, pause_start))
            if pause_end < end:
                cut.append((pause_end, end))
        pieces = cut
    return tuple(pieces)


def hidden_intervals(config: dict) -> tuple:
    """When the rubber arm is out of view in every condition: ``rubber_arm.hidden_times`` and, with
    ``readings.hide_arm``, the readings, merged where they touch or overlap; ((start_s, end_s), ...) in order."""
    intervals = [(float(a), float(b)) for a, b in config["rubber_arm"]["hidden_times"]]
    if config["readings"]["hide_arm"]:
        intervals += reading_intervals(config["readings"])
    merged = []
    for start, end in sorted(intervals):
        if merged and start <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], end))
        else:
            merged.append((start, end))
    return tuple(merged)


def check_probes(probes, length: float) -> None:
    """``experiment.probe_times``: finite seconds within the trial, [0, ``length``], strictly increasing."""
    if not isinstance(probes, list) or not all(finite(t) for t in probes):
        raise ConfigError(f"experiment.probe_times = {probes!r} must be a list of finite times, s")
    for time in probes:
        if not 0 <= time <= length:
            raise ConfigError(f"experiment.probe_times: {time:g} s is beyond the trial, which lasts {length:g} s "
                              "(experiment.steps x experiment.step_size)")
    if any(later <= earlier for earlier, later in zip(probes, probes[1:])):
        raise ConfigError(f"experiment.probe_times = {probes!r} must be strictly increasing")


def check(config: dict) -> None:
    """Every schedule key of ``config``: the stimulations' ``touch`` and ``blocks``, ``stimulus.stroke_duration``,
    ``rubber_arm.hidden_conditions`` and ``hidden_times``, ``[readings]`` and ``experiment.probe_times``; a
    ConfigError naming the first bad one."""
    period, length = config["stimulus"]["period"], trial_length(config)
    for name, stimulation in config["stimulations"].items():
        if not isinstance(stimulation.get("touch", True), bool):
            raise ConfigError(f"stimulations.{name}.touch = {stimulation['touch']!r} must be true or false")
        check_blocks(name, stimulation.get("blocks", []), period, length)
    stroke = config["stimulus"]["stroke_duration"]
    if not (stroke > 0 and (stroke <= period or math.isinf(stroke))):
        raise ConfigError(f"stimulus.stroke_duration = {stroke:g} s must be positive and at most stimulus.period = "
                          f"{period:g} s (inf: the whole period)")
    hidden = config["rubber_arm"]["hidden_conditions"]
    if not isinstance(hidden, list) or not all(isinstance(name, str) for name in hidden):
        raise ConfigError(f"rubber_arm.hidden_conditions = {hidden!r} must be a list of condition names")
    for name in hidden:
        if name not in config["conditions"]:
            raise ConfigError(f"rubber_arm.hidden_conditions: {name!r} is not defined in [conditions]")
        if hidden.count(name) > 1:
            raise ConfigError(f"rubber_arm.hidden_conditions lists {name!r} more than once")
    check_intervals("rubber_arm.hidden_times", config["rubber_arm"]["hidden_times"], length)
    check_readings(config["readings"], length)
    check_probes(config["experiment"]["probe_times"], length)
