"""Stimulation schedules and probes: the checks of their configuration keys (docs/configuration.md,
"Stimulation schedules"), each refusal one line naming the key.

A stimulation (``[stimulations.NAME]``) strokes in ``blocks`` ([[start_s, end_s], ...], in order, not
overlapping; [] = one block over the whole trial) and with ``touch`` (false: vision only); the ball's
stroke lasts ``stimulus.stroke_duration`` of each ``stimulus.period``; ``rubber_arm.hidden_conditions``
names the conditions without a rubber arm in view; ``experiment.probe_times`` are the times at which
the drift is read besides the end of the trial.
"""
from __future__ import annotations

import math

from rhi.components.stimulus import MAX_BLOCKS
from rhi.master.cosim import ConfigError


def trial_length(config: dict) -> float:
    """The trial's length, s: ``experiment.steps`` x ``experiment.step_size``."""
    return config["experiment"]["steps"] * config["experiment"]["step_size"]


def finite(value) -> bool:
    """Whether ``value`` is a finite int or float (not a Boolean)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_blocks(name: str, blocks, period: float, length: float) -> None:
    """``stimulations.NAME.blocks``: at most MAX_BLOCKS [start, end] pairs of seconds with 0 <= start < end,
    each at least one ``period`` long (else it holds no touch), starting before the trial ends (``length``), in
    order and not overlapping; else a ConfigError naming the key."""
    key = f"stimulations.{name}.blocks"
    if not isinstance(blocks, list) or len(blocks) > MAX_BLOCKS:
        raise ConfigError(f"{key} must be a list of at most {MAX_BLOCKS} [start_s, end_s] pairs, got {blocks!r}")
    previous_end = 0.0
    for block in blocks:
        if not (isinstance(block, list) and len(block) == 2 and all(finite(v) for v in block)):
            raise ConfigError(f"{key}: {block!r} must be a pair [start_s, end_s] of finite numbers")
        start, end = block
        if not 0 <= start < end:
            raise ConfigError(f"{key}: block {block!r} needs 0 <= start < end, s")
        if start < previous_end:
            raise ConfigError(f"{key}: block {block!r} overlaps the block before it, which ends at {previous_end:g} s "
                              "(blocks in order, not overlapping)")
        if end - start < period:
            raise ConfigError(f"{key}: block {block!r} is shorter than stimulus.period = {period:g} s, so it holds "
                              "no touch")
        if start >= length:
            raise ConfigError(f"{key}: block {block!r} starts at or after the trial's end, {length:g} s "
                              "(experiment.steps x experiment.step_size)")
        previous_end = end


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
    ``rubber_arm.hidden_conditions`` and ``experiment.probe_times``; a ConfigError naming the first bad one."""
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
    check_probes(config["experiment"]["probe_times"], length)
