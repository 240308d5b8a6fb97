"""A task of one's own, in one file: the rubber arm moved further from the real hand in the middle of a trial.

The paper's protocol (any model, any condition), its trials 120 s long, but at ``moved_arm.move_time_s`` (60 s) the
rubber arm jumps ``moved_arm.shift_cm`` (10 cm) further from the real hand, along x, away from it. The drift is read
just before the move and at the end: does the belief follow the arm it now sees farther away? Run it as any task::

    rhi run examples/my_task.py:MovedArm --model causal --out moved
    rhi.run("examples/my_task.py:MovedArm", model="causal")        # in memory: .tables()["drift.csv"]

and in a sweep (``[sweep] task = "examples/my_task.py:MovedArm"``); ``moved_arm.*`` are configuration keys like
any other (``--config``, a sweep's grid).
"""
import dataclasses

import numpy as np
import pandas as pd

from rhi.components.body.rubber_arm import RubberArm
from rhi.components.variables import Variable
from rhi.master.cosim import ConfigError
from rhi.master.tasks.base import Task
from rhi.master.tasks.illusion.task import Illusion


class MovingRubberArm(RubberArm):
    """The rubber arm, moved ``shift`` m further from the real hand (along x, away from it) at ``move_time`` s."""

    def __init__(self, name: str = "rubber_arm"):
        super().__init__(name)
        for variable in (Variable("move_time", "parameter", start=60.0, unit="s", description="when the arm moves"),
                         Variable("shift", "parameter", start=0.1, unit="m", description="how far it moves, away")):
            self.variables[variable.name] = variable

    def initialize(self):
        super().initialize()
        self.moved = False

    def step(self, t, h):
        if not self.moved and t + h >= self.values["move_time"][0] - 1e-9:  # the move, at the step that reaches it
            away = np.where(self.values["offset_x"] < 0, -1.0, 1.0)
            self.values["offset_x"] = self.values["offset_x"] + away * self.values["shift"]
            self.values["pose"], self.values["hand"] = self._pose()
            self.moved = True


class MovedArm(Illusion):
    """The paper's protocol with the rubber arm moved further away mid-trial; the drift before and after."""

    name = "moved-arm"
    summary = "the rubber arm moved 10 cm further from the real hand mid-trial; the drift before and after"
    command = ""
    own_settings = {"moved_arm": {"move_time_s": 60.0, "shift_cm": 10.0},
                    "experiment": {"steps": 6000}}  # 120 s of 0.02 s steps: 60 s before the move, 60 s after
    simulate = Task.simulate  # the generic run: each decoder's trials in one lockstep batch
    figures = Task.figures   # no figures

    def load(self, path=None, overrides=None, quick=False, model_name="paper"):
        """The illusion's configuration with [moved_arm]; the move must fall inside the trial."""
        config = super().load(path, overrides, quick, model_name)
        length = config["experiment"]["steps"] * config["experiment"]["step_size"]
        if not 0 < config["moved_arm"]["move_time_s"] < length:
            raise ConfigError(f"moved_arm.move_time_s = {config['moved_arm']['move_time_s']:g} s must fall inside the "
                              f"trial (0 to {length:g} s = experiment.steps x step_size)")
        return config

    def scenario(self, config, kind, trials=(), checkpoint=None):
        scenario = super().scenario(config, kind, trials, checkpoint)
        return dataclasses.replace(scenario, world=tuple(MovingRubberArm() if part.name == "rubber_arm" else part
                                                         for part in scenario.world))

    def parameters(self, trials, config, system):
        moved = config["moved_arm"]
        return {**super().parameters(trials, config, system), "rubber_arm.move_time": moved["move_time_s"],
                "rubber_arm.shift": moved["shift_cm"] / 100.0}

    def before(self, times, config) -> int:
        """The row of the last step before the move."""
        return max(int(np.searchsorted(times, config["moved_arm"]["move_time_s"] - 1e-9)) - 1, 0)

    def measures(self, result, config, trials):
        """The illusion's measures, and the drift just before the move (at every row: a sweep's trial reads it)."""
        per_step = super().measures(result, config, trials)
        row = self.before(result.times, config)
        return {**per_step, "drift_at_move_cm": np.broadcast_to(per_step["drift_cm"][row], per_step["drift_cm"].shape)}

    def tables(self, result):
        """drift.csv: per trial, the drift just before the move and at the end (cm)."""
        return {"drift.csv": pd.DataFrame({
            "decoder": [t.decoder for t in result.trials], "condition": [t.condition for t in result.trials],
            "stimulation": [t.stimulation for t in result.trials], "trial": [t.index for t in result.trials],
            "drift_before_cm": result.per_step["drift_at_move_cm"][-1], "drift_after_cm": result.per_step["drift_cm"][-1]})}
