"""The task contract: what a task declares, the one run of any task (:func:`run`), and its result
(:class:`TaskResult`), whose :meth:`~TaskResult.write` is the one writer of a task's folder and its run.json.

A task is a :class:`Task`: its name, a one-line summary, its settings file beside its module, and one fixed set of
methods, the same signature for every task:

- ``load(path, overrides, quick, model_name) -> config``: the defaults, the model, the task's settings, the file;
- ``plan(config) -> trials``: every trial, each with its ``decoder`` (the slot whose decoder it runs with);
- ``scenario(config, kind, trials, checkpoint) -> Scenario``: the system of decoder ``kind``'s trials, as data;
- ``parameters(trials, config, system) -> dict``: the system's parameters for those trials;
- ``measures(result, config, trials) -> dict``: per step and trial (steps + 1, B) of one batch's recorded values;
- ``tables(result) -> {file name: text or pandas.DataFrame}``, ``figures(result, folder) -> [file names]``.

:meth:`Task.simulate` runs them (each decoder's trials in one lockstep batch); a built-in task may run its own way
(failure isolation, worker processes), as long as it returns a :class:`TaskResult`. The FMI export hooks
(``trial_name``, ``parse_trial``, ``links``, ``agent_values``, ``agent``, ``model_name``, ``system_name``,
``system_description``, ``trial_form``, ``trials``) are optional: a task without them cannot be exported
(:attr:`Task.exportable`).
"""
from __future__ import annotations

import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rhi.master import config as configuration
from rhi.master import models
from rhi.master.cosim import ConfigError
from rhi.master.outputs import tables
from rhi.master.outputs.files import atomic_write, check_output, output_folder
from rhi.master.outputs.provenance import package_versions, write_run_record
from rhi.master.runtime.context import RunContext

EXPORT_HOOKS = ("agent", "model_name", "system_name", "system_description", "trial_form", "trials", "trial_name",
                "parse_trial", "links", "agent_values")
_NAME = re.compile(r"[a-z][a-z0-9-]*")


class Task:
    """A task: what the agent does, around any registered model.

    Attributes
    ----------
    name : str
        Lower case, digits and hyphens (``moving-hand``).
    summary : str
        One line on what the agent does in it.
    settings : str
        Its settings file, beside its module (``""``: none); its tables merge over the defaults and the model's.
    command : str
        What run.json records as the command that ran it.
    source : str
        The spec it was loaded from (``""``: built in; set by the registry).
    """

    name: str = ""
    summary: str = ""
    settings: str = ""
    command: str = ""
    source: str = ""

    # -- the contract ---------------------------------------------------------------------------------------
    def load(self, path=None, overrides: dict | None = None, quick: bool = False, model_name: str = "paper") -> dict:
        """The task's configuration: the defaults (and their ``[quick]``), the model, :meth:`settings_file` (and
        its ``[quick]``), the file ``path``, ``overrides`` (``{"table.key": value}``); checked."""
        config = configuration.defaults()
        quick_values = config.pop("quick")
        if quick:
            config = configuration.merge(config, quick_values)
        config = configuration.with_model(config, model_name)
        own = configuration.read_toml(self.settings_file()) if self.settings else {}
        own_quick = own.pop("quick", {})
        config = configuration.merge({**config, **{key: value for key, value in own.items() if key not in config}},
                                     {key: value for key, value in own.items() if key in config})
        if quick:
            config = configuration.merge(config, own_quick)
        if path is not None:
            config = configuration.merge(config, configuration.read_toml(path))
        config = configuration.merge(config, configuration.nest(overrides or {}))
        configuration.validate(config)
        return config

    def plan(self, config: dict) -> list:
        """Every trial, in order; each has a ``decoder``."""
        raise NotImplementedError

    def scenario(self, config: dict, kind: str, trials=(), checkpoint: str | None = None):
        """The system of decoder ``kind``'s ``trials`` as data (:class:`rhi.master.tasks.scene.Scenario`);
        ``checkpoint``: the decoder's (default: the configuration's or the cached one)."""
        raise NotImplementedError

    def parameters(self, trials: list, config: dict, system) -> dict:
        """The parameters of ``system`` for ``trials``: ``{"component.variable": scalar or (B, ...) array}``."""
        raise NotImplementedError

    def measures(self, result, config: dict, trials: list) -> dict:
        """Each measure per step and trial, (steps + 1, B), of one batch's :class:`rhi.master.cosim.Result` (of
        ``trials``)."""
        raise NotImplementedError

    def tables(self, result: "TaskResult") -> dict:
        """``{file name: text or pandas.DataFrame}``: the tables the run writes."""
        raise NotImplementedError

    def figures(self, result: "TaskResult", folder: Path) -> list[str]:
        """Write the figures into ``folder``; returns their names (default: none)."""
        return []

    # -- how it runs ------------------------------------------------------------------------------------------
    def check(self) -> None:
        """ConfigError (one line) unless the declarations hold: a name, a summary, the contract's methods, a
        settings file that is there."""
        if not isinstance(self.name, str) or not _NAME.fullmatch(self.name):
            raise ConfigError(f"task name must be lower-case letters, digits and hyphens, got {self.name!r}")
        if not isinstance(self.summary, str) or not self.summary:
            raise ConfigError(f"task {self.name}: summary must say in one line what the agent does")
        for method in ("plan", "scenario", "parameters", "measures", "tables"):
            if getattr(type(self), method) is getattr(Task, method) and not self.runs_its_own_way(method):
                raise ConfigError(f"task {self.name}: {method}() is not defined (rhi.master.tasks.Task)")
        if self.settings and not Path(self.settings_file()).is_file():
            raise ConfigError(f"task {self.name}: settings file {self.settings_file()} is not there")

    def runs_its_own_way(self, method: str) -> bool:
        """Whether ``method`` is left out because :meth:`simulate` is the task's own (a built-in's)."""
        return method != "tables" and type(self).simulate is not Task.simulate

    def settings_file(self) -> str:
        """Its settings file's path: :attr:`settings` beside the module of the class that declares it."""
        declaring = next(cls for cls in type(self).__mro__ if "settings" in vars(cls))
        return str(Path(sys.modules[declaring.__module__].__file__).parent / self.settings)

    @property
    def exportable(self) -> bool:
        """Whether the task has every FMI export hook (:data:`EXPORT_HOOKS`)."""
        return all(hasattr(self, hook) for hook in EXPORT_HOOKS)

    def check_before_work(self, config: dict, context: RunContext) -> None:
        """What can be checked before any work (default: the decoders' checkpoints or training settings)."""
        from rhi.master.decoders.cache import check_decoders
        check_decoders(config, context.device)

    def simulate(self, config: dict, context: RunContext, workers=None) -> "TaskResult":
        """Every trial of :meth:`plan`: each decoder's in one lockstep batch, here, measured (:meth:`measures`)."""
        from rhi.master.decoders.cache import ensure_checkpoints
        from rhi.master.tasks.scene import run as run_scenario

        checkpoints, training = ensure_checkpoints(config, progress=context.progress, device=context.device,
                                                   workers=workers)
        trials, blocks, times, began = [], [], None, time.perf_counter()
        for kind in config["experiment"]["decoders"]:
            mine = [trial for trial in self.plan(config) if trial.decoder == kind]
            if not mine:
                continue
            result = run_scenario(self.scenario(config, kind, mine, checkpoints[kind]), config,
                                  lambda system, batch=mine: self.parameters(batch, config, system), len(mine),
                                  trials=mine)
            trials += mine
            blocks.append(self.measures(result, config, mine))
            times = result.times
        if not blocks:
            raise ConfigError(f"task {self.name}: its plan has no trial for decoders "
                              f"{', '.join(config['experiment']['decoders'])}")
        per_step = {key: np.concatenate([np.asarray(block[key]) for block in blocks], axis=-1) for key in blocks[0]}
        provenance = {"command": self.command or f"rhi run {self.source or self.name}", "task": self.name,
                      "model": models.of(config).name, "configuration": config, "checkpoints": checkpoints,
                      "seeds": {"master": config["experiment"]["seed"],
                                "trials": [getattr(t, "__dict__", str(t)) for t in trials]},
                      "timings_s": {"training": training, "trials": time.perf_counter() - began}}
        return TaskResult(self, config, trials, times, per_step, provenance)


@dataclass
class TaskResult:
    """A task's run, in memory: what its folder holds, before it is written.

    Attributes
    ----------
    task : Task
    config : dict
        The configuration it ran.
    trials : list
        The trials that ran to the end, in the plan's order.
    times : numpy.ndarray
        (steps + 1,) s.
    per_step : dict of str to numpy.ndarray
        Each measure per step and trial, (steps + 1, len(trials)) (:meth:`Task.measures`).
    provenance : dict
        What run.json records (the writer adds the figures and the total time).
    failures : dict
        Each failed trial and its error.
    began : float
        ``time.perf_counter()`` when the run began.
    """

    task: Task
    config: dict
    trials: list
    times: np.ndarray
    per_step: dict
    provenance: dict = field(default_factory=dict)
    failures: dict = field(default_factory=dict)
    began: float = 0.0

    def tables(self) -> dict:
        """``{file name: text or DataFrame}`` (:meth:`Task.tables`)."""
        return self.task.tables(self)

    def write(self, out, force: bool = False, workers=None) -> None:
        """Publish DIR = ``out`` whole or not at all (a staging folder renamed): the tables, the figures, run.json."""
        check_output(out, force)
        with output_folder(out, force) as staging:
            self.write_files(Path(staging), workers)

    def write_files(self, staging: Path, workers=None) -> None:
        """The task's files (:meth:`write_tables`, its figures) and run.json into the folder ``staging``."""
        self.write_tables(staging, workers)
        figures = self.write_figures(staging, workers)
        provenance = {"schema_version": tables.SCHEMA_VERSION, **self.provenance, "versions": package_versions()}
        if (staging / "figures").is_dir():
            provenance["figures"] = sorted(path.name for path in (staging / "figures").iterdir())
        elif figures:
            provenance["figures"] = sorted(figures)
        provenance["timings_s"] = {**provenance.get("timings_s", {}), "total": time.perf_counter() - self.began}
        write_run_record(staging, provenance)

    def write_figures(self, staging: Path, workers=None) -> list[str]:
        """The task's figures (:meth:`Task.figures`) into ``staging``; their names."""
        return self.task.figures(self, staging)

    def write_tables(self, staging: Path, workers=None) -> None:
        """Each of :meth:`tables` as a file (a DataFrame as CSV without its index)."""
        for name, table in self.tables().items():
            atomic_write(staging / name, table_text(table))


def table_text(table) -> str:
    """A table as the text of its file: text as it is, a DataFrame as CSV (no index, ``\\n`` line ends)."""
    return table if isinstance(table, str) else table.to_csv(index=False, lineterminator="\n")


def run(task: Task, config: dict | None = None, context: RunContext | None = None, workers=None) -> TaskResult:
    """Run ``task`` under ``config`` (default: the task's own, :meth:`Task.load`) in memory.

    Parameters
    ----------
    task : Task
    config : dict, optional
    context : RunContext, optional
        progress, device, processes.
    workers : rhi.master.runtime.pool.Workers, optional
        Worker processes to run on (left open).

    Returns
    -------
    TaskResult
    """
    began, context = time.perf_counter(), context or RunContext()
    config = task.load() if config is None else config
    task.check_before_work(config, context)
    result = task.simulate(config, context, workers)
    result.began = began
    return result


def run_into(task: Task, out, config: dict, context: RunContext | None = None) -> TaskResult:
    """Run ``task`` and write DIR = ``out`` as :meth:`TaskResult.write` does. The settings are checked first
    (:meth:`Task.check_before_work`: before any folder is made or decoder trained), then the folder and its staging
    folder (one that cannot be written is refused before the run, not after it)."""
    from rhi.master.runtime.pool import Workers

    began, context = time.perf_counter(), context or RunContext()
    task.check_before_work(config, context)
    check_output(out, context.force)
    with output_folder(out, context.force) as staging, \
            Workers(1 if context.device != "cpu" else context.processes) as workers:
        result = task.simulate(config, context, workers)
        result.began = began
        result.write_files(Path(staging), workers)
    return result
