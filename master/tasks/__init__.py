"""Tasks: what the agent does, each described as data (a :class:`rhi.master.tasks.scene.Scenario`: the task's
components, links and records) and built around any registered model (:mod:`rhi.master.models`) by one function,
:func:`rhi.master.tasks.scene.build`.

:data:`TASKS` registers them: the command that runs each and the function that describes its scenario. Every
task runs every model (``tests/test_models.py`` runs each registered task with each registered model from the
command line).
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Task:
    """A registered task.

    Attributes
    ----------
    name : str
        The task's name.
    summary : str
        One line on what the agent does in it.
    command : tuple of str
        The ``rhi`` command (and its first arguments) that runs it, into ``--out DIR``, with ``--model``.
    scenario : str
        ``module:function`` returning its :class:`~rhi.master.tasks.scene.Scenario` (documentation: where to look;
        the command imports it).
    """

    name: str
    summary: str
    command: tuple
    scenario: str


TASKS = {task.name: task for task in (
    Task("illusion", "the paper's protocol: the hidden arm held, the rubber arm seen and touched, in time or late",
         ("experiment",), "rhi.master.tasks.illusion.wiring:scenario"),
    Task("reach", "the free arm reaching to a seen goal, near and far", ("reach",),
         "rhi.master.tasks.reach.task:scenario"),
    Task("moving-hand", "the free arm swinging, the rubber arm repeating the movement after a delay, no touch",
         ("phenomenon", "moving-hand"), "rhi.master.tasks.moving_hand:scenario"),
    Task("reach-after", "the illusion's trial, then a reach to a target once the touches stop",
         ("phenomenon", "reach-after"), "rhi.master.tasks.reach_after:scenario"),
)}
