"""The protocol: which trials run, and the seed and parameters that make each one differ.

Per-trial seeds are hashes of (master seed, condition, stimulation, index), so both decoders
see the same delays and the same master seed gives the same bytes.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from rhi.components.body import kinematics
from rhi.master.config import population
from rhi.master.config.schedules import hidden_intervals, stroking_blocks

HALF_RANGES = (40.0, 50.0)  # deg: shoulder, elbow, about the rest pose: the arm's working ranges in every task, and so
#                                the decoders' training ranges (docs/design.md)

@dataclass(frozen=True)
class Trial:
    """One trial of the protocol and everything that makes it differ from the others."""

    decoder: str
    condition: str
    stimulation: str
    index: int
    seed: int
    offset_x: float
    delay_min: float
    delay_max: float
    # ((key, value), ...): this trial's own values of parameter keys (sources.batchable_keys), in a lockstep
    # batch that runs several configurations at once (a sweep's chunk of several points); () = the config's
    overrides: tuple = ()
    touch: bool = True         # the stimulation's touch: tactile events follow the visual ones (false: vision only)
    blocks: tuple = ()         # the stroking blocks ((start_s, end_s), ...), the readings cut out; () = one over the trial
    arm_visible: bool = True   # the rubber arm is in view (false: the condition is in rubber_arm.hidden_conditions)
    hidden: tuple = ()         # ((start_s, end_s), ...): when the rubber arm is out of view (hidden times, readings)


def trial_seed(master_seed: int, condition: str, stimulation: str, index: int) -> int:
    """A stable 63-bit seed per trial. Independent of the decoder, so both decoders see the same delays."""
    digest = hashlib.sha256(f"{master_seed}/{condition}/{stimulation}/{index}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


def make_trial(config: dict, decoder: str, condition: str, stimulation: str, index: int,
               overrides: tuple = ()) -> Trial:
    """The trial of this cell and repetition under ``config``: its seed, rubber-hand offset and whether it is in
    view (and when not: the hidden times and readings), and its stimulation's delay law, touch and blocks (less
    the readings, which pause the stroking).

    overrides: ``((key, value), ...)``, the trial's own values of parameter keys in a batch of several
    configurations (:func:`rhi.master.config.sources.parameters` gives them to the components per trial). The
    participant's own values, drawn from the ``[population]`` table (:func:`rhi.master.config.population.participant`:
    participant ``index``), follow them and so win: a batch of several configurations passes each point's
    configured value of every batchable key, which is the median the participant's draw is centred on.
    """
    delays = config["stimulations"][stimulation]
    if population.entries(config):
        overrides = tuple(overrides) + population.participant(config, index)
    return Trial(decoder, condition, stimulation, index,
                 trial_seed(config["experiment"]["seed"], condition, stimulation, index),
                 float(config["conditions"][condition]), float(delays["delay_min"]), float(delays["delay_max"]),
                 tuple(overrides), bool(delays.get("touch", True)),
                 stroking_blocks(delays.get("blocks", []), config.get("readings", NO_READINGS)),
                 condition not in config["rubber_arm"].get("hidden_conditions", []),
                 hidden_intervals({"rubber_arm": {"hidden_times": config["rubber_arm"].get("hidden_times", [])},
                                   "readings": config.get("readings", NO_READINGS)}))


NO_READINGS = {"times": [], "duration": 0.0, "hide_arm": False}  # a configuration from before [readings]


def table_rows(config: dict, trials=()) -> tuple[int, int]:
    """The rows the stimulus generator's ``blocks`` and ``hidden`` tables have in a run of ``config``: the most blocks
    and hidden intervals of a trial of its protocol or of ``trials`` (at least one row each)."""
    every = [*plan(config), *trials]
    return (max([len(t.blocks) for t in every] + [1]), max([len(t.hidden) for t in every] + [1]))


def plan(config: dict) -> list[Trial]:
    """Every trial of the protocol, in a fixed order: decoder, condition, stimulation, index."""
    experiment = config["experiment"]
    return [make_trial(config, decoder, condition, stimulation, index)
            for decoder in experiment["decoders"]
            for condition in experiment["conditions"]
            for stimulation in experiment["stimulations"]
            for index in range(experiment["trials"])]


def rubber_pose(offset_x: float, offset_y: float = 0.0) -> tuple[float, float]:
    """Joint angles (deg) of the rubber arm whose hand is offset from the real resting hand."""
    shoulder, elbow = kinematics.inverse(kinematics.REST_HAND[0] + offset_x, kinematics.REST_HAND[1] + offset_y)
    return float(shoulder), float(elbow)


def per_trial(trials: list[Trial], config: dict, key: str):
    """The value of configuration ``key`` for the components: the configuration's, or, when some trial carries
    its own (``Trial.overrides``, a batch of several configurations), one value per trial, shape (B,)."""
    table, name = key.split(".")
    value = config[table][name]
    if not any(t.overrides for t in trials):
        return value
    values = [dict(t.overrides).get(key, value) for t in trials]
    return value if all(v == value for v in values) else np.array(values, dtype=float)
