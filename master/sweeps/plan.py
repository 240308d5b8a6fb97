"""Parameter sweeps: points over the experiment's configuration, run as Dask tasks of lockstep batches.

A sweep file is an experiment configuration (any tables of defaults.toml, fixed for every point)
plus a ``[sweep]`` table saying what varies::

    [sweep]
    trials = 3                     # per point and decoder x condition x stimulation (= experiment.trials)
    quick = true                   # start from the [quick] defaults, like `rhi experiment --quick`
    # preset = "paper"             # or from a shipped preset, like `rhi experiment --preset paper`
    model = "causal"               # the model (master/models/NAME.toml), like `rhi experiment --model`; paper by default
    # task = "examples/my_task.py:MovedArm"  # a task of one's own (FILE.py:Class or a registered name), or a
                                             # trial function (package.module:function); the illusion by default
    batch = 10                     # at most this many trials per task (default: all of a point's decoder)
    workers = 2                    # processes of the local pool (default: one per core)
    [sweep.grid]                   # every combination, in file order, the last key varying fastest
    "stimulations.sync.delay_max" = [0.1, 0.5, 1.0]
    "decoder.visual_variance" = [1000.0, 3000.0]
    # or instead of [sweep.grid], a list of points:
    # [[sweep.points]]
    # "conditions.left" = -0.3

A trial is one cell of the protocol (decoder x condition x stimulation of the point's experiment
table) and one index below its trials. With the experiment's own trial function (the default task)
a Dask task is a *chunk*: the trials of one point and decoder, in the protocol's order, run in one
lockstep batch as `rhi experiment` runs them, split into near-equal consecutive chunks of at most
``batch`` trials. The chunks are fixed by the file alone, never by the workers or by what a folder
already holds, because a trial's numbers may depend on its batch (BLAS kernels differ by batch size;
the fast mode shares linearisation points within a batch). Any other task is called once per trial,
``task(config, decoder, condition, stimulation, index)``: a chunk of one.

A trial's id hashes everything that decides its result: the task, the point's full configuration,
the cell, the index, the seed, and for a batched task the trials of its chunk. The engine runs the
chunks on any dask.distributed Client (a local process pool or a remote cluster) and writes each
trial's record as soon as its chunk arrives, on the client's machine.
"""
from __future__ import annotations

import hashlib
import importlib
import itertools
import math
import json
from dataclasses import dataclass
from pathlib import Path

from rhi.master import models
from rhi.master import config as configuration
from rhi.master.cosim import ConfigError
from rhi.master.runtime.pool import workers_problem
from rhi.master.tasks import illusion as experiment

# The illusion's identity in every trial's id and a folder's fingerprint (``sweep.task = "illusion"``, the
# default): the name its trial function had once, kept so that the folders of earlier sweeps resume.
DEFAULT_TASK = "master.experiment:trial_outcome"
MOVED_TASKS = {DEFAULT_TASK: "rhi.master.tasks.illusion:trial_outcome"}


def canonical_task(name):
    """``sweep.task`` as the plan records it: ``"illusion"`` (a registered name) is :data:`DEFAULT_TASK`."""
    return DEFAULT_TASK if name == "illusion" else name


def is_task(name: str) -> bool:
    """Whether ``sweep.task`` names a registered task or a task class of one's own (``FILE.py:Class``), not a
    trial function (``module:function``)."""
    from rhi.master import tasks

    return name != DEFAULT_TASK and (name in tasks.names() or name.partition(":")[0].endswith(".py"))


def task_location(name: str) -> str:
    """Where the trial function of ``sweep.task`` is imported from (a task's: :class:`TaskTrial`'s module)."""
    return f"{__name__}:TaskTrial" if is_task(name) else MOVED_TASKS.get(name, name)


@dataclass(frozen=True)
class TaskTrial:
    """A sweep's trial of a task (``sweep.task``, resolved on the worker): :meth:`Task.outcome` of the protocol's
    trial (decoder, condition, stimulation, index) under the point's configuration."""

    spec: str

    def __call__(self, config: dict, decoder: str, condition: str, stimulation: str, index: int) -> dict:
        from rhi.master import tasks

        return tasks.get(self.spec).outcome(config, experiment.make_trial(config, decoder, condition, stimulation,
                                                                          index))


def sweep_task(name: str):
    """The task object of ``sweep.task`` (None for a trial function); ConfigError unless it runs the protocol's
    trials one by one (``outcome(config, trial)``)."""
    if not is_task(name):
        return None
    from rhi.master import tasks

    try:
        task = tasks.get(name)
    except ConfigError as error:
        raise ConfigError(f"sweep.task: {error}") from None
    if not callable(getattr(task, "outcome", None)):
        raise ConfigError(f"sweep.task {name!r}: a sweep runs the illusion protocol's trials, and this task has no "
                          "outcome(config, trial) (tasks built on rhi.master.tasks.illusion.task.Illusion have)")
    return task
SWEEP_KEYS = ("trials", "quick", "preset", "model", "task", "batch", "workers", "grid", "points")
BATCHING = "lockstep-chunks/1"  # in the fingerprint of a batched sweep: folders of per-trial sweeps differ


@dataclass(frozen=True)
class TrialSpec:
    """One trial of a sweep: which point, which cell of the protocol, which repetition."""

    id: str
    point: int
    decoder: str
    condition: str
    stimulation: str
    index: int
    seed: int


@dataclass(frozen=True)
class Sweep:
    """A checked sweep file: its points, their configurations, and the trials it runs, in order.

    Attributes
    ----------
    task : str
        The trial function, ``module:function``.
    points : list of dict
        Per point: dotted key -> value, as written in the file.
    keys : list of str
        The swept keys, in first-seen order.
    configs : list of dict
        Per point: the full effective configuration.
    workers : int or None
        The local pool's size; None: one per core.
    trials : list of TrialSpec
        The plan, in order: point, decoder, condition, stimulation, index.
    fingerprint : str
        A hash of the whole plan: the same fingerprint, the same trials.
    chunks : list of list of int
        One Dask task each: positions in ``trials``, a lockstep batch (or one trial).
    batched : bool
        True: the experiment's own trial function, run a chunk at a time.
    """

    task: str                   # "module:function"
    points: list[dict]          # per point: dotted key -> value, as written in the file
    keys: list[str]             # the swept keys, in first-seen order
    configs: list[dict]         # per point: the full effective configuration
    workers: int | None         # local pool size; None = one per core
    trials: list[TrialSpec]     # the plan, in order: point, decoder, condition, stimulation, index
    fingerprint: str            # hash of the whole plan: same fingerprint, same trials
    chunks: list[list[int]]     # one Dask task each: positions in ``trials``, a lockstep batch (or one trial)
    batched: bool               # True: the experiment's own trial function, run a chunk at a time


def identity(config: dict) -> dict:
    """``config`` as it enters a trial's id and a sweep's fingerprint: without ``experiment.body`` where it is the
    default pymunk arm, so that the trials planned before the key existed keep their ids and folders."""
    from rhi.master.config.bodies import DEFAULT

    if config.get("experiment", {}).get("body") != DEFAULT:
        return config
    return {**config, "experiment": {k: v for k, v in config["experiment"].items() if k != "body"}}


def canonical_hash(value) -> str:
    """sha256 (hex) of ``value`` as canonical JSON: keys sorted, no spaces, NaN and infinities allowed."""
    text = json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def flatten(table: dict, prefix: str = "") -> dict:
    """``{"a": {"b": 1}, "c.d": 2}`` -> ``{"a.b": 1, "c.d": 2}``: dotted keys, quoted or not."""
    flat = {}
    for key, value in table.items():
        if isinstance(value, dict):
            flat.update(flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


# A sweep's points: each is validated and planned before any trial runs (a few ms each), so 10,000 take
# about a minute; far beyond the shipped sweeps (at most a few dozen points).
MAX_POINTS = 10_000


def grid_points(grid: dict) -> list[dict]:
    """Every combination of the grid's values; file order, the last key varying fastest."""
    flat = flatten(grid)
    for key, values in flat.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f"sweep.grid.{key} must be a non-empty list of values, got {values!r}")
    count = math.prod(len(values) for values in flat.values())
    if count > MAX_POINTS:
        raise ConfigError(f"sweep.grid has {count} points, over the limit of {MAX_POINTS} (each is checked and "
                          "planned before the sweep starts); split the sweep")
    return [dict(zip(flat, combination)) for combination in itertools.product(*flat.values())]


def listed_points(points) -> list[dict]:
    """``sweep.points`` (a non-empty list of tables) as points of dotted keys; ConfigError otherwise."""
    if not isinstance(points, list) or not points or not all(isinstance(p, dict) for p in points):
        raise ConfigError("sweep.points must be a non-empty list of tables ([[sweep.points]])")
    return [flatten(point) for point in points]


def resolve_task(name: str):
    """The trial function of ``sweep.task``: a task's (:class:`TaskTrial`), or the callable named
    ``module:function``; a ConfigError naming it when it cannot be imported."""
    name = canonical_task(name)
    if sweep_task(name) is not None:
        return TaskTrial(name)
    module_name, _, function_name = task_location(name).partition(":")
    if not module_name or not function_name:
        raise ConfigError(f"sweep.task must be 'module:function', got {name!r}")
    try:
        function = getattr(importlib.import_module(module_name), function_name)
    except (ImportError, AttributeError) as error:
        raise ConfigError(f"sweep.task {name!r} cannot be imported: {error}") from None
    if not callable(function):
        raise ConfigError(f"sweep.task {name!r} is not a function")
    return function


def check_settings(settings: dict) -> None:
    """Check the ``[sweep]`` table: known keys, whole numbers of at least 1, a boolean quick, a known preset and
    model, a string task, and no two keys that exclude each other; ConfigError naming the key."""
    for key in settings:
        if key not in SWEEP_KEYS:
            raise configuration.unknown_key(f"sweep.{key}", SWEEP_KEYS, "sweep")
    for key in ("trials", "workers", "batch"):
        value = settings.get(key, 1)
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise ConfigError(f"sweep.{key} must be a whole number of at least 1, got {value!r}")
    problem = workers_problem("sweep.workers", settings.get("workers", 1))
    if problem:
        raise ConfigError(problem)
    if not isinstance(settings.get("quick", False), bool):
        raise ConfigError(f"sweep.quick must be true or false, got {settings['quick']!r}")
    if "preset" in settings and settings["preset"] not in configuration.PRESETS:
        raise ConfigError(f"sweep.preset = {settings['preset']!r} is not one of {', '.join(configuration.PRESETS)}")
    if "model" in settings:
        models.checked(settings["model"], "sweep.model")
    if settings.get("quick") and "preset" in settings:
        raise ConfigError("sweep: give either sweep.quick or sweep.preset, not both")
    if not isinstance(settings.get("task", DEFAULT_TASK), str):
        raise ConfigError(f"sweep.task must be a string: a task's name, FILE.py:Class or 'module:function', got "
                          f"{settings['task']!r}")
    if "grid" in settings and "points" in settings:
        raise ConfigError("sweep: give either sweep.grid or sweep.points, not both")
    if "batch" in settings and settings.get("task", DEFAULT_TASK) != DEFAULT_TASK:
        raise ConfigError(f"sweep.batch applies to the default task {DEFAULT_TASK} only; "
                          f"sweep.task {settings['task']!r} is called once per trial")


def point_config(base: dict, point: dict, number: int) -> dict:
    """The full configuration of point ``number``: ``point`` merged over ``base`` and validated; ConfigError naming
    the point."""
    try:
        effective = configuration.merge(base, configuration.nest(point))
        configuration.validate(effective)
    except ConfigError as error:
        raise ConfigError(f"sweep point {number} ({describe(point)}): {error}") from None
    return effective


def describe(point: dict) -> str:
    """A point in words: ``key=value, ...`` (values as JSON), or ``no parameters``."""
    return ", ".join(f"{key}={json.dumps(value)}" for key, value in point.items()) or "no parameters"


def chunk_cells(configs: list[dict], batch: int | None,
                points_per_batch: int = 1) -> list[list[tuple[int, experiment.Trial]]]:
    """Per chunk: its (point, protocol trial) pairs. Per group of points (:func:`batch_groups`) and decoder, the
    protocol's trials in its order, split into the fewest near-equal consecutive chunks of at most ``batch``
    (None: one chunk); the larger chunks first. Depends on the configurations, ``batch`` and ``points_per_batch``
    alone."""
    chunks = []
    for group in batch_groups(configs, points_per_batch):
        trials = [(number, t) for number in group for t in experiment.plan(configs[number])]
        for decoder in configs[group[0]]["experiment"]["decoders"]:
            mine = [(number, t) for number, t in trials if t.decoder == decoder]
            count = -(-len(mine) // batch) if batch else 1
            size, extra = divmod(len(mine), count)
            start = 0
            for part in range(count):
                end = start + size + (part < extra)
                chunks.append(mine[start:end])
                start = end
    return chunks


def batch_groups(configs: list[dict], points_per_batch: int) -> list[range]:
    """The points that share a lockstep batch: each run of consecutive points that differ only where a batch lets
    its trials differ (the batchable parameter keys, :func:`rhi.master.config.sources.batchable_keys`, the master
    seed, the conditions' offsets, the stimulations' delays, the population: each trial's own), cut into groups of
    ``points_per_batch`` (1: each point alone). A fit of several protocols gives one run per protocol."""
    from rhi.master.config.sources import batchable_keys

    def shared(config: dict) -> str:
        kept = {table: dict(values) if isinstance(values, dict) else values for table, values in config.items()
                if table not in ("conditions", "stimulations", "population")}
        kept["experiment"].pop("seed")
        for key in batchable_keys(config):
            table, name = key.split(".")
            kept[table].pop(name, None)
        return canonical_hash(kept)

    if points_per_batch == 1:
        return [range(number, number + 1) for number in range(len(configs))]
    hashes, groups, first = [shared(config) for config in configs], [], 0
    for end in [n for n in range(1, len(configs)) if hashes[n] != hashes[n - 1]] + [len(configs)]:
        groups += [range(start, min(start + points_per_batch, end)) for start in range(first, end, points_per_batch)]
        first = end
    return groups


def plan(configs: list[dict], task: str, batch: int | None = None,
         points_per_batch: int = 1) -> tuple[list[TrialSpec], list[list[int]]]:
    """Every trial of the sweep, in order (point, decoder, condition, stimulation, index), and its chunks.

    The default task runs a chunk of trials in one lockstep batch (:func:`chunk_cells`), and a trial's
    id names its chunk's members too (with ``points_per_batch`` > 1 each member's configuration as well);
    any other task runs each trial alone, a chunk of one.
    """
    batched = task == DEFAULT_TASK
    chunks = chunk_cells(configs, batch, points_per_batch) if batched else [
        [(n, t)] for n, c in enumerate(configs) for t in experiment.plan(c)]
    trials, positions = [], []
    for chunk in chunks:
        members = [[t.condition, t.stimulation, t.index] for _, t in chunk]
        if points_per_batch > 1:
            members = [[canonical_hash(identity(configs[n]))[:20], *member] for member, (n, _) in zip(members, chunk)]
        positions.append(list(range(len(trials), len(trials) + len(chunk))))
        for number, t in chunk:
            named = {"task": task, "config": identity(configs[number]), "decoder": t.decoder,
                     "condition": t.condition, "stimulation": t.stimulation, "index": t.index, "seed": t.seed,
                     **({"batch": members} if batched else {})}
            trials.append(TrialSpec(canonical_hash(named)[:20], number, t.decoder, t.condition,
                                    t.stimulation, t.index, t.seed))
    return trials, positions


def base_config(path: str | Path, model: str | None = None, trials: int | None = None) -> tuple[dict, dict]:
    """The sweep file's checked configuration before its points (the defaults, its quick or preset, the model,
    the file's own tables) and its checked [sweep] settings; model, trials as :func:`load` takes them."""
    fixed = configuration.read_toml(path)
    settings = fixed.pop("sweep", None)
    if not isinstance(settings, dict):
        raise ConfigError(f"sweep file {path} has no [sweep] table (it says what to vary)")
    settings = {**settings, **({"model": model} if model else {}), **({"trials": trials} if trials else {})}
    if "task" in settings:
        settings["task"] = canonical_task(settings["task"])
    check_settings(settings)
    resolve_task(settings.get("task", DEFAULT_TASK))
    own = sweep_task(settings.get("task", DEFAULT_TASK))
    start = (own.load(None, {}, settings.get("quick", False), settings.get("model", "paper"))
             if own is not None and "preset" not in settings else
             configuration.load(quick=settings.get("quick", False), preset_name=settings.get("preset"),
                                model_name=settings.get("model", "paper")))
    base = configuration.merge(start, fixed)
    configuration.validate(base)
    return base, settings


def load(path: str | Path, model: str | None = None, trials: int | None = None) -> Sweep:
    """Read and check a sweep file; every point's configuration is validated before anything runs.

    model, trials: instead of the file's ``sweep.model`` and ``sweep.trials`` (`rhi phenomenon --model`).
    """
    base, settings = base_config(path, model, trials)
    task = settings.get("task", DEFAULT_TASK)
    if "trials" in settings:
        base["experiment"]["trials"] = settings["trials"]
    points = (grid_points(settings["grid"]) if "grid" in settings
              else listed_points(settings["points"]) if "points" in settings else [{}])
    return build(base, points, task, settings.get("batch"), settings.get("workers"))


def build(base: dict, points: list[dict], task: str = DEFAULT_TASK, batch: int | None = None,
          workers: int | None = None, points_per_batch: int = 1) -> Sweep:
    """The sweep of ``points`` (dotted key -> value each) over the checked configuration ``base``: every point's
    configuration validated, the trials planned and chunked.

    points_per_batch: with the default task, this many consecutive points share each lockstep batch (1: a
    point's trials alone), each run of points that differ only per trial cut into such groups (:func:`batch_groups`).
    """
    configs = [point_config(base, point, number) for number, point in enumerate(points)]
    seen: dict[str, int] = {}
    for number, config in enumerate(configs):
        other = seen.setdefault(canonical_hash(config), number)
        if other != number:
            raise ConfigError(f"sweep points {other} and {number} are the same configuration")
    batched = task == DEFAULT_TASK
    if not batched:
        points_per_batch = 1
    trials, chunks = plan(configs, task, batch, points_per_batch)
    keys = list(dict.fromkeys(key for point in points for key in point))
    planned = {"task": task, "configs": [identity(c) for c in configs], "points": points}
    if batched:
        planned.update(batching=BATCHING, batch=batch)
        if points_per_batch > 1:
            planned.update(points_per_batch=points_per_batch)
    return Sweep(task, points, keys, configs, workers, trials, canonical_hash(planned), chunks, batched)
