"""The tasks an agent FMU and an SSP package carry (``--task``): what differs between them, in one place.

- ``illusion``: the experiment (master/tasks/illusion/wiring.py); its configuration ``config.load``, one
  parameter file per trial of the protocol (``conv_left_sync_0``: its condition, delays and seed);
- ``reach``: the free arm reaching to a seen goal (master/tasks/reach/task.py); its configuration
  ``reach.load`` (``body.held = false``), one parameter file per goal of the reach plan (``conv_near_0``:
  the goal pose).

Each gives :func:`rhi.master.export.ssp_package.build_ssp` its trials, their names, the agent's parameters per
trial, the body's links and the system's name; the agent components are master/export/agent.py's.
"""
from __future__ import annotations

import numpy as np

from rhi.master.cosim import ConfigError
from rhi.master import config as configuration
from rhi.master.tasks.reach import task as reach
from rhi.master.tasks.illusion import wiring
from rhi.master.config.sources import parameters
from rhi.master.config.protocol import Trial, make_trial, plan
from rhi.master.export.agent import SEED, SEED_HIGH, SEED_LOW, body_links, exposed, split_seed


def agent_parameters(trial: Trial, config: dict, declared: dict) -> dict:
    """The agent FMU's parameters for ``trial``: ``{name: (type, value)}`` from :func:`rhi.master.config.sources.parameters`
    (the experiment's own values), the seed split into two Integers."""
    given = parameters([trial], config)
    values = {}
    for path, value in given.items():
        name = path.partition(".")[2]
        if path == SEED:
            low, high = split_seed(int(value[0]))
            values[SEED_LOW], values[SEED_HIGH] = ("Integer", low), ("Integer", high)
        elif exposed(path, config) and declared.get(name, ("",))[0] == "parameter":
            values[name] = (declared[name][1], np.asarray(value).reshape(-1)[0])
    return values


class Illusion:
    """The rubber-hand illusion: the experiment's protocol, trial by trial."""

    name = "illusion"
    agent, model_name = "rhi.master.export.agent:Agent", "RubberHandAgent"  # the component; the FMI model identifier
    system_name, system_description = "RubberHandIllusion", "the rubber-hand agent and a body"
    trial_form = "CONDITION/STIMULATION/INDEX, e.g. left/sync/0"

    def load(self, path, overrides: dict, quick: bool, model_name: str = "paper") -> dict:
        """The experiment's configuration (``rhi.master.config.load``): the file ``path``, ``overrides``, ``quick``,
        the model."""
        return configuration.load(path, overrides, quick=quick, model_name=model_name)

    def trials(self, config: dict, kind: str) -> list[Trial]:
        """The protocol's trials of decoder ``kind``, in the protocol's order."""
        return [t for t in plan(config) if t.decoder == kind]

    def trial_name(self, trial: Trial) -> str:
        """``conv_left_sync_0``: a trial's parameter file, without folder and suffix."""
        return f"{trial.decoder}_{trial.condition}_{trial.stimulation}_{trial.index}"

    def parse_trial(self, text: str, config: dict, kind: str) -> Trial:
        """``left/sync/0`` -> the protocol's trial of decoder ``kind`` (ConfigError naming what is unknown)."""
        parts = text.split("/")
        if len(parts) != 3 or not parts[2].isdigit():
            raise ConfigError(f"--trial {text!r} must be {self.trial_form}")
        condition, stimulation, index = parts[0], parts[1], int(parts[2])
        for table, value in (("conditions", condition), ("stimulations", stimulation)):
            if value not in config[table]:
                raise ConfigError(f"--trial {text!r}: no {table[:-1]} {value!r} (have: {', '.join(config[table])})")
        return make_trial(config, kind, condition, stimulation, index)

    def links(self, config: dict) -> list[tuple[str, str]]:
        """The body's links: the experiment's (``wiring.CONNECTIONS``)."""
        return body_links()

    def agent_values(self, trial: Trial, config: dict, declared: dict, starts: dict) -> dict:
        """The agent FMU's parameters for ``trial``, ``{name: (type, value)}`` (:func:`agent_parameters`; ``starts``
        unused)."""
        return agent_parameters(trial, config, declared)


class Reach:
    """The free arm reaching to a seen goal: the reach plan, goal by goal."""

    name = "reach"
    agent, model_name = "rhi.master.export.reach_agent:ReachAgent", "ReachAgent"
    system_name, system_description = "RubberHandReach", "the reach agent and a free body"
    trial_form = "BAND/INDEX, e.g. near/0"

    def load(self, path, overrides: dict, quick: bool, model_name: str = "paper") -> dict:
        """The reach's configuration (``rhi.master.tasks.reach.task.load``): the file ``path``, overrides, quick, the
        model."""
        return reach.load(path, quick=quick, model_name=model_name, overrides=overrides)

    def trials(self, config: dict, kind: str) -> list[reach.ReachTrial]:
        """The reach plan's goals for decoder ``kind`` (the same goals for each decoder)."""
        return reach.plan({**config, "experiment": {**config["experiment"], "decoders": [kind]}})

    def trial_name(self, trial: reach.ReachTrial) -> str:
        """``conv_near_0``: a goal's parameter file, without folder and suffix."""
        return f"{trial.decoder}_{trial.band}_{trial.index}"

    def parse_trial(self, text: str, config: dict, kind: str) -> reach.ReachTrial:
        """``near/0`` -> the reach plan's goal of decoder ``kind`` (ConfigError naming what is unknown)."""
        parts = text.split("/")
        if len(parts) != 2 or not parts[1].isdigit():
            raise ConfigError(f"--trial {text!r} must be {self.trial_form}")
        band, index = parts[0], int(parts[1])
        if band not in config["reach"]["bands"]:
            raise ConfigError(f"--trial {text!r}: no band {band!r} (have: {', '.join(config['reach']['bands'])})")
        if index >= config["reach"]["goals"]:
            raise ConfigError(f"--trial {text!r}: no goal {index} (reach.goals = {config['reach']['goals']})")
        return next(t for t in self.trials(config, kind) if (t.band, t.index) == (band, index))

    def links(self, config: dict) -> list[tuple[str, str]]:
        """The body's links in the reach system (the sensed joints in, the action out)."""
        return body_links(reach.connections(config))

    def agent_values(self, trial: reach.ReachTrial, config: dict, declared: dict, starts: dict) -> dict:
        """Every parameter of the reach agent FMU at its start (the configuration's, which built it), the goal
        pose the trial's: ``{name: (type, value)}``."""
        values = {name: (kind, starts[name]) for name, (causality, kind) in declared.items() if causality == "parameter"}
        values["goal_shoulder"], values["goal_elbow"] = ("Real", trial.goal_pose[0]), ("Real", trial.goal_pose[1])
        return values


TASKS = {task.name: task for task in (Illusion(), Reach())}


def task(name: str):
    """The task of ``--task name``; ConfigError if there is none."""
    if name not in TASKS:
        raise ConfigError(f"--task {name!r} is not one of {', '.join(TASKS)}")
    return TASKS[name]
