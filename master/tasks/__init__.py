"""Tasks: what the agent does, each a registered :class:`~rhi.master.tasks.base.Task` that describes its system as
data (a :class:`~rhi.master.tasks.scene.Scenario`) built around any registered model (:mod:`rhi.master.models`) by
one function, :func:`rhi.master.tasks.scene.build`.

:data:`TASKS` is the one registry. A task's name resolves as a model's does:

- a built-in name, ``illusion``, ``reach``, ``moving-hand`` or ``reach-after`` (:data:`BUILT_IN`);
- a Python entry point in the group ``rhi.tasks`` (``name = "package.module:Class"``);
- ``path/to/file.py:Class`` or ``package.module:Class``: a task of one's own in one file (``examples/my_task.py``).

Every task runs every model (``tests/test_models.py``), in memory (:func:`rhi.master.tasks.base.run`) and from the
command line (``rhi run TASK``), with the same tables both ways.

Example::

    from rhi.master.tasks import TASKS, run
    task = TASKS["moving-hand"]
    result = run(task, task.load(overrides={"moving_hand.delays": [0.0]}))
    result.tables()["moving_hand.csv"]
"""
from __future__ import annotations

from collections.abc import Mapping
from importlib import metadata

from rhi.master.cosim import ConfigError
from rhi.master.runtime.plugins import load_object
from rhi.master.tasks.base import Task, TaskResult, run, run_into

__all__ = ["Task", "TaskResult", "TASKS", "BUILT_IN", "ENTRY_POINT_GROUP", "get", "names", "described", "run",
           "run_into", "exportable"]

# the built-in tasks, imported when first named (a phenomenon's task adds its human references one floor up)
BUILT_IN = {"illusion": "rhi.master.tasks.illusion.task:Illusion", "reach": "rhi.master.tasks.reach.publish:Reach",
            "moving-hand": "rhi.master.phenomena.moving_hand:MovingHand",
            "reach-after": "rhi.master.tasks.reach_after:ReachAfter"}
ENTRY_POINT_GROUP = "rhi.tasks"
_LOADED: dict[str, Task] = {}  # spec -> the task object, once per process


def names() -> tuple[str, ...]:
    """Every task known by name here: the built-in ones, then the entry points'."""
    found = dict(BUILT_IN)
    for point in metadata.entry_points(group=ENTRY_POINT_GROUP):
        found.setdefault(point.name, point.value)
    return tuple(found)


def spec_of(name: str) -> str:
    """The ``module:Class`` or ``file.py:Class`` a task's name stands for (a spec stands for itself)."""
    if name in BUILT_IN:
        return BUILT_IN[name]
    for point in metadata.entry_points(group=ENTRY_POINT_GROUP):
        if point.name == name:
            return point.value
    if ":" in name:
        return name
    raise ConfigError(f"task {name!r} is unknown; choose one of {', '.join(names())}, or give "
                      "path/to/file.py:Class or package.module:Class")


def get(name: str) -> Task:
    """The task ``name`` (built-in, an entry point's, ``file.py:Class`` or ``module:Class``), checked: a ConfigError
    of one line for an unknown name, a file or class that is not there, a class that is not a :class:`Task`, or
    declarations that do not hold (:meth:`Task.check`)."""
    if not isinstance(name, str) or not name:
        raise ConfigError(f"task must be a name or path/to/file.py:Class, got {name!r}")
    spec = spec_of(name)
    if spec not in _LOADED:
        task = load_object(spec, "task")
        if not isinstance(task, Task):
            raise ConfigError(f"task {spec!r}: {spec.rpartition(':')[2]} is not a rhi.master.tasks.Task")
        task.source = "" if spec in BUILT_IN.values() else spec
        task.check()
        _LOADED[spec] = task
    return _LOADED[spec]


def exportable(name: str) -> Task:
    """The registered task ``name`` if it has the FMI export hooks (the exporters' ``--task``; an agent FMU names its
    task, so a task of one's own by path is not one); else a ConfigError of one line naming those that have."""
    able = []
    for known in names():
        try:
            if get(known).exportable:
                able.append(known)
        except ConfigError:  # a broken plug-in breaks only a run that uses it
            continue
    if name not in able:
        raise ConfigError(f"--task {name!r} is not one of {', '.join(able)} (the tasks an agent FMU can carry)")
    return get(name)


def described() -> str:
    """The tasks in words, for a command's help: each built-in name with its summary, each entry point's name."""
    return "; ".join(f"{name} = {get(name).summary}" if name in BUILT_IN else f"{name} = {spec_of(name)}"
                     for name in names()) + "; or path/to/file.py:Class, a task of one's own (examples/my_task.py)"


class Registry(Mapping):
    """The registered tasks by name (:func:`names`); ``TASKS[spec]`` also resolves a ``file.py:Class``."""

    def __getitem__(self, name: str) -> Task:
        return get(name)

    def __iter__(self):
        return iter(names())

    def __len__(self) -> int:
        return len(names())

    def __contains__(self, name) -> bool:
        return isinstance(name, str) and name in names()

    def __repr__(self) -> str:
        return f"TASKS{list(names())}"


TASKS = Registry()
