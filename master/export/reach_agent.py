"""The reach agent (goal arm, goal camera, goal decoder, brain, wired as ``rhi reach``) as ONE component.

:class:`ReachAgent` is :class:`~rhi.master.export.agent.Agent` with the reach system inside
(:func:`rhi.master.tasks.reach.task.build_system` without its body), for the free arm (``body.held = false``)
reaching to a goal it sees (docs/reach.md). Its ports:

- inputs: what the body feeds the inside (the sensed joint angles), as the illusion agent's;
- outputs: the action, then :data:`REACH_OBSERVED` where the inside has them (mu, gamma, the free energy,
  the goal's term, the goal's hand) and the perceived hand;
- parameters: the goal pose ``goal_shoulder``, ``goal_elbow`` (absolute joint angles, deg; start: the
  reach plan's first goal, the same for both decoders), the goal's ``precision_ratio`` w, the seen image's
  ``visual_variance`` (the goal image's is visual_variance / w) and the other scalar parameters the
  illusion agent exposes of the components inside (:func:`~rhi.master.export.agent.parameter_paths`: the brain's).

Each parameter but the goal stands for a configuration key: the inner parameters are
:func:`rhi.master.tasks.reach.task.parameters` of the configuration with the agent's values in those keys,
and the goal pose as given, so that ``System([agent, body])`` is ``rhi reach``'s system step for step
(tests/test_reach_agent.py checks it bitwise). A goal outside the joint ranges the decoders know
(:func:`rhi.master.tasks.reach.task.goal_problem`) fails the initialization, naming the joint.

Example::

    agent = ReachAgent("conv.pt", "conv", reach.load(quick=True))
    system = System([agent, ArmPlant()], agent.connections())   # with body.held = false
"""
from __future__ import annotations

import functools

import numpy as np

from rhi.components.component import ComponentError
from rhi.components.variables import Variable
from rhi.master.cosim import System
from rhi.master.tasks.reach import task as reach
from rhi.master.tasks.illusion import wiring
from rhi.master.config.sources import config_key, sources
from rhi.master.decoders.training_data import HALF_RANGES
from rhi.master.export.agent import OBSERVED, Agent, parameter_paths

GOAL = {"goal_shoulder": "goal.shoulder", "goal_elbow": "goal.elbow"}  # FMI name -> the goal arm's parameter
RATIO, RATIO_KEY = "precision_ratio", "reach.precision_ratio"
VISUAL_VARIANCE = "decoder.visual_variance"  # the seen image's; the goal decoder's is derived from it
# FMI name, inner path, element or None[, the description, {} the inner one's]: where the inside has the path.
REACH_OBSERVED = OBSERVED[:3] + (
    ("free_energy", "brain.free_energy", None, "{}; plus goal_error"),
) + OBSERVED[4:6] + (
    ("goal_error", "goal_decoder.visual_error", None,
     "the goal's term, 1/2 (s_goal - g)^T (s_goal - g) * 256^2/(H W) / (visual_variance / w), s_goal the goal "
     "image (not weighted by gamma)"),
    ("goal_error", "goal_attractor.goal_error", None, "the goal's term, {}"),
    ("visual_error", "decoder.visual_error", None),
    ("goal_hand_x", "goal.hand", 0, "the goal arm's hand position (x, y)"),
    ("goal_hand_y", "goal.hand", 1, "the goal arm's hand position (x, y)"),
)


class ReachAgent(Agent):
    """The reach agent (goal arm, goal camera, goal decoder or encoder, brain) as one component with scalar ports.

    Its parameters are :class:`Agent`'s, but ``config`` is a reach configuration
    (``rhi.master.tasks.reach.task.load``): the resolution, the camera's blur, the decoder's mode, the goal's term
    and view, and the start values of the parameters.
    """

    task = "reach"
    summary = "the reach agent (goal arm, goal camera, {kind} goal decoder at {resolution} px, brain)"
    perceived = "the belief's hand; goal_hand_x, goal_hand_y: the goal's"

    def __init__(self, checkpoint: str, kind: str, config: dict, name: str = "agent"):
        self.keys = {}  # FMI name -> the configuration key it stands for (all but the goal)
        super().__init__(checkpoint, kind, config, name)

    def whole_system(self) -> System:
        """The reach system of this decoder, its body included, with new components."""
        return reach.build_system(self.kind, self.checkpoint, self.config)

    @functools.cached_property
    def observed(self) -> tuple:
        """:data:`REACH_OBSERVED` where the inside has the path, each name once (the first)."""
        chosen = []
        for entry in REACH_OBSERVED:
            if present(self._system, entry[1]) and entry[0] not in [e[0] for e in chosen]:
                chosen.append(entry)
        return tuple(chosen)

    def parameter_variables(self) -> list[Variable]:
        """The goal, its precision ratio, the seen image's variance, and the illusion agent's rule for the rest."""
        inner = self._system
        first = reach.plan(self.config)[0]  # the same goals for both decoders
        variables = []
        for (name, path), angle, half in zip(GOAL.items(), first.goal_pose, HALF_RANGES):
            declared = inner.variable(path)
            variables.append(Variable(name, "parameter", start=angle, unit=declared.unit, min=declared.min,
                                      max=declared.max, description=f"the goal's {declared.description}, absolute; "
                                      f"within rest ± {half:g} deg, the range the decoders know (checked at "
                                      f"initialization)"))
        variables.append(Variable(RATIO, "parameter", start=self.config["reach"]["precision_ratio"], unit="1",
                                  min=0.0, description="w: the goal's precision relative to the seen image's "
                                                       "(released agent: 2); the goal image's variance is "
                                                       "visual_variance / w"))
        self.keys[RATIO] = RATIO_KEY
        paths = parameter_paths(inner, self.config)
        if ("goal_decoder" in inner.components or "decoder" in inner.components) and VISUAL_VARIANCE not in paths:
            paths.insert(0, VISUAL_VARIANCE)
        for path in paths:
            name, key = path.partition(".")[2], config_key(sources(self.config)[path])
            declared = inner.variable(path if present(inner, path) else "goal_decoder." + name)
            table, entry = key.split(".")
            variables.append(Variable(name, "parameter", declared.type, start=self.config[table][entry],
                                      unit=declared.unit, min=declared.min, max=declared.max,
                                      description=declared.description))
            self.keys[name] = key
        self.parameters = dict(GOAL)
        return variables

    def check_parameters(self):
        """The goal within the joint ranges the decoders know, and a positive, finite precision ratio."""
        problem = reach.goal_problem(self.values["goal_shoulder"], self.values["goal_elbow"])
        ratio = self.values[RATIO]
        if problem is None and not np.all(np.isfinite(ratio) & (ratio > 0)):
            problem = f"{RATIO} must be positive and finite, got {ratio.tolist()}"
        if problem:
            raise ComponentError(f"{self.name}: {problem}")

    def inner_parameters(self) -> dict:
        """:func:`rhi.master.tasks.reach.task.parameters` of the configuration with this agent's values in their
        keys, and the goal pose as given (checked first: :meth:`check_parameters`)."""
        self.check_parameters()
        config = dict(self.config)
        for name, key in self.keys.items():
            table, entry = key.split(".")
            config[table] = {**config[table], entry: self.values[name]}
        trials = [reach.ReachTrial(self.kind, "agent", 0, 0, 0.0, 0.0)] * self.batch_size  # its goal is set below
        given = reach.parameters(trials, config, self._system)
        for name, path in GOAL.items():
            given[path] = self.values[name]
        return given


def present(system: System, path: str) -> bool:
    """Whether ``system`` has the variable ``path`` (``component.variable``)."""
    name, _, variable = path.partition(".")
    return name in system.components and variable in system.components[name].variables
