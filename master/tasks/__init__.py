"""Tasks: what the agent does, each a system assembled around any registered model (:mod:`master.models`) by the
one assembly, :func:`master.tasks.scene.assemble`.

:data:`TASKS` registers them: the command that runs each and where its system is built. Every task runs every
model (``tests/test_models.py`` runs each registered task with each registered model from the command line).
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
    system : str
        ``module:function`` building its system around the configuration's model (documentation: where to
        look; the command imports it).
    """

    name: str
    summary: str
    command: tuple
    system: str


TASKS = {task.name: task for task in (
    Task("illusion", "the paper's protocol: the hidden arm held, the rubber arm seen and touched, in time or late",
         ("experiment",), "master.tasks.illusion.wiring:build_system"),
    Task("reach", "the free arm reaching to a seen goal, near and far", ("reach",),
         "master.tasks.reach.task:build_system"),
    Task("moving-hand", "the free arm swinging, the rubber arm repeating the movement after a delay, no touch",
         ("phenomenon", "moving-hand"), "master.phenomena.moving_hand:decoder_delays"),
    Task("reach-after", "the illusion's trial, then a reach to a target once the touches stop",
         ("phenomenon", "reach-after"), "master.phenomena.reach_after:decoder_trials"),
)}
