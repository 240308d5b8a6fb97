"""The experiment in memory (:func:`run_experiment`) and into a folder (:func:`run_into`, ``rhi experiment``):
train what is missing, run the protocol, measure; its tables and figures (written by
:meth:`rhi.master.tasks.base.TaskResult.write`, whole or not at all).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from rhi.master import models
from rhi.master.tasks.illusion import runner
from rhi.master.runtime.context import RunContext
from rhi.master.tasks.illusion.runner import body_factory
from rhi.master.decoders.cache import check_decoders, ensure_checkpoints, jacobian_pair
from rhi.master.tasks.illusion.fast_check import verdicts
from rhi.master.runtime.pool import Workers, call
from rhi.master.tasks.illusion.measures import end_of_trial
from rhi.master.config import population
from rhi.master.config.protocol import plan, rubber_pose
from rhi.master.outputs import cohort, figures, tables
from rhi.master.outputs.files import atomic_write
from rhi.master.tasks.base import TaskResult
from rhi.master.outputs.animation import frames, gif_bytes

log = logging.getLogger("rhi.experiment")


@dataclass
class ExperimentResult(TaskResult):
    """The protocol's run, in memory: what ``rhi experiment`` writes into DIR, before it is written
    (:class:`rhi.master.tasks.base.TaskResult`, and the illusion's own).

    Attributes
    ----------
    per_step : dict of str to numpy.ndarray
        Each measure per step and trial, (steps + 1, len(trials)) (:func:`rhi.master.tasks.illusion.measures.measures`).
    final : dict of str to numpy.ndarray
        Each measure at the end of the trial, (len(trials),).
    summary : list of list
        The rows of summary.csv (columns ``rhi.master.outputs.tables.summary_columns``).
    provenance : dict
        What run.json records: the model, the body, checkpoints, fast-mode verdicts, seeds, timings.
    """

    final: dict = field(default_factory=dict)
    summary: list = field(default_factory=list)

    def write_tables(self, staging, workers=None) -> None:
        """summary.csv (participants.csv), then trials.csv and figures/ side by side on ``workers`` (else here)."""
        texts = table_texts(self, with_trials=False)
        for name, text in texts.items():
            atomic_write(staging / name, text)
        write_figures(self, staging, workers, with_trials=True)

    def write_figures(self, staging, workers=None) -> list[str]:
        """None here: the figures are written with trials.csv, side by side (:meth:`write_tables`)."""
        return []  # written with trials.csv (write_tables)


def table_texts(result: ExperimentResult, with_trials: bool = True) -> dict[str, str]:
    """summary.csv (participants.csv for a population that varies) and trials.csv, as text."""
    config = result.config
    columns = tables.summary_columns(config["experiment"]["probe_times"])
    measures = cohort_measures(config)
    texts = {"summary.csv": tables.csv_text(columns + cohort.columns(measures, columns), result.summary)}
    if measures:
        texts["participants.csv"] = participants_text(config)
    if with_trials:
        texts["trials.csv"] = tables.trials_csv(result.trials, result.times, result.per_step)
    return texts


def write_figures(result: ExperimentResult, folder, workers: Workers | None, with_trials: bool = False) -> list[str]:
    """figures/ in ``folder`` (and trials.csv with ``with_trials``), the files side by side on ``workers`` (None:
    here), the longest first; the figures' names."""
    trials, per_step, config = result.trials, result.per_step, result.config
    (folder / "figures").mkdir()
    if cohort_measures(config):
        cohort.write_strip_figure(folder / "figures" / "cohort.png", trials, result.final,
                                  [*cohort.STRIPS, *models.of(config).measures])
    shown = next((i for i, t in enumerate(trials) if (t.condition, t.stimulation) == ("left", "sync")), 0)
    name = f"trial_{trials[shown].decoder}_{trials[shown].condition}_{trials[shown].stimulation}.gif"
    animated = {key: per_step[key][:, shown] for key in ANIMATED}
    jobs = [(write_trials, folder / "trials.csv", trials, result.times, per_step),
            (write_per_step, folder / "per_step.nc", result)] if with_trials else []
    jobs += [(write_jacobians, folder / "figures" / "h_jacobians.png", result.provenance["checkpoints"], config),
             (write_animation, folder / "figures" / name, trials[shown], animated, config["experiment"]["resolution"]),
             *figures.panel_jobs(folder / "figures", trials, result.times, per_step, result.final, None)]
    if workers is None:
        for job in jobs:
            call(*job)
    else:
        workers.map(call, jobs, start=False)
    log.debug(f"wrote the tables and figures into {folder}")
    return sorted(path.name for path in (folder / "figures").iterdir())


def run_experiment(config: dict | None = None, body: str | None = None, context: RunContext | None = None,
                   workers: Workers | None = None) -> ExperimentResult:
    """The paper's protocol under ``config`` (default: the shipped configuration), in memory.

    Trains the decoders the configuration needs and does not find, checks the fast mode, runs every trial in
    lockstep batches (failures isolated), and measures them; ``result.write(DIR)`` publishes the folder
    ``rhi experiment`` writes.

    Parameters
    ----------
    config : dict, optional
        A configuration (:func:`rhi.master.config.load`); any registered model (``[model]``).
    body : str, optional
        An FMU to use as the body (default: the native pymunk plant).
    context : RunContext, optional
        progress, device (cpu, cuda; resolved), processes (default: the usable cores).
    workers : Workers, optional
        Worker processes to run on (left open); default: workers of its own.

    Returns
    -------
    ExperimentResult

    Example::

        from rhi.master.tasks.illusion import run_experiment
        from rhi.master import config
        result = run_experiment(config.load(quick=True, model_name="causal"))
        result.final["drift_cm"]         # (trials,) cm
    """
    from rhi.master.tasks import TASKS, run

    return run(TASKS["illusion"].with_body(body), config, context, workers)


def checked_before_work(config: dict, body: str | None, device: str):
    """What can be checked before any training or run: the decoders' checkpoints or training settings (and the
    model's pose encoders), the body FMU; returns the body's parameter names (None: the native plant)."""
    check_decoders(config, device)
    return body_factory(body, config)[1]


def simulate_protocol(config: dict, body: str | None, context: RunContext, workers: Workers, declared, task=None):
    """:func:`run_experiment` on ``workers`` once checked (``declared``: :func:`checked_before_work`'s); the
    caller sets the result's ``began``."""
    checkpoints, training_seconds = ensure_checkpoints(config, progress=context.progress, device=context.device,
                                                       workers=workers)
    checked = time.perf_counter()
    modes = verdicts(config, checkpoints, workers, context.progress)
    check_seconds = time.perf_counter() - checked
    log.debug("decoders: " + ", ".join(f"{kind} {path} ({'fast' if modes[kind]['fast'] else 'exact'} mode)"
                                       for kind, path in checkpoints.items()))
    trials, times, per_step, run_seconds, failures = runner.run(
        config, checkpoints, body, context, fast={kind: mode["fast"] for kind, mode in modes.items()}, workers=workers)
    probe_times = config["experiment"]["probe_times"]
    final = end_of_trial(times, per_step, probe_times)
    planned = tables.cells(plan(config))
    summary = tables.summary(trials, final, planned=planned, probe_times=probe_times)
    measures = cohort_measures(config)
    if measures:  # a population that varies: the between-participant statistics appended to each row
        present = tables.summary_columns(probe_times)
        summary = [row + more for row, more in
                   zip(summary, cohort.summary_cells(trials, final, planned, measures, present))]
    log.debug(f"measured {len(trials)} trials into {len(summary)} cells ({len(failures)} failed)")
    provenance = {
        "command": "rhi experiment", "task": "illusion", "model": models.of(config).name,
        "configuration": config, "body": body or "native pymunk plant",
        "body_keys_not_declared": sorted(f"body.{key}" for key in config["body"]
                                         if declared is not None and key not in declared),
        "checkpoints": checkpoints, "fast_mode": modes, "device": context.device,
        "seeds": {"master": config["experiment"]["seed"], "trials": [t.__dict__ for t in trials]},
        "timings_s": {"training": training_seconds, "fast_check": check_seconds, "trials": run_seconds},
        "failed_trials": [{**trial.__dict__, "error": error} for trial, error in failures.items()],
    }
    if task is None:
        from rhi.master.tasks import TASKS
        task = TASKS["illusion"].with_body(body)
    return ExperimentResult(task, config, trials, times, per_step, provenance, failures, final=final, summary=summary)


def run_into(out, config: dict, body: str | None = None, context: RunContext | None = None) -> dict:
    """Run the protocol of ``config`` and write DIR = ``out`` (:func:`rhi.master.tasks.base.run_into`); returns
    {failed trial: error}.

    body: an FMU to use as the body (None: the native pymunk plant). context: force (replace DIR of rhi's),
    progress, device (where the decoders train and run: cpu, cuda; resolved). Everything that can be checked is
    checked before any training: the output folder, the decoders' checkpoints (kind, resolution, camera) or
    training settings, the body FMU.
    """
    from rhi.master.tasks import TASKS, run_into as run_task_into

    return run_task_into(TASKS["illusion"].with_body(body), out, config, context).failures


def cohort_measures(config: dict) -> dict[str, str]:
    """The measures whose between-participant statistics summary.csv appends (:mod:`rhi.master.outputs.cohort`):
    none unless the configuration's population varies, so that a run without one keeps its bytes."""
    if not population.varies(config):
        return {}
    return cohort.measures_of(tuple(models.of(config).measures),
                              tuple(tables.probe_measures(config["experiment"]["probe_times"])))


def participants_text(config: dict) -> str:
    """participants.csv: every participant the protocol plans (``experiment.trials``), with its drawn values."""
    indices = range(config["experiment"]["trials"])
    seeds = [population.participant_seed(config["experiment"]["seed"], index) for index in indices]
    return cohort.participants_csv(indices, seeds, population.cohort(config, indices))


ANIMATED = ("ball_x_m", "ball_y_m", "mu_shoulder_deg", "mu_elbow_deg")  # the measures the animation shows


def write_trials(path, trials, times, per_step) -> None:
    """trials.csv (a job of :func:`run_into`)."""
    atomic_write(path, tables.trials_csv(trials, times, per_step))


def per_step_dataset(result: ExperimentResult):
    """Every measure per trial and step, unrounded, as an xarray Dataset.

    Parameters
    ----------
    result : ExperimentResult
        A run of the protocol.

    Returns
    -------
    xarray.Dataset
        One variable per measure, dims ``trial`` (len(trials)) x ``time_s`` (steps + 1); coordinates ``decoder``,
        ``condition``, ``stimulation``, ``index`` and ``seed`` along ``trial``; attributes ``model`` and ``seed``.
    """
    import xarray as xr

    trials = result.trials
    along = {key: ("trial", np.array([getattr(t, key) for t in trials])) for key in
             ("decoder", "condition", "stimulation", "index", "seed")}
    data = {key: (("trial", "time_s"), np.asarray(values).T) for key, values in result.per_step.items()}
    return xr.Dataset(data, coords={"trial": np.arange(len(trials)), "time_s": result.times, **along},
                      attrs={"model": models.of(result.config).name, "seed": result.config["experiment"]["seed"]})


def write_per_step(path, result: ExperimentResult) -> None:
    """per_step.nc: :func:`per_step_dataset` as NetCDF-4 (h5netcdf; NetCDF-3 holds no 64-bit seeds), each
    variable zlib-compressed (level 4) and the bytes the same for the same run (a job of :func:`run_into`)."""
    dataset = per_step_dataset(result)
    encoding = {name: {"zlib": True, "complevel": 4} for name in dataset.data_vars}
    atomic_write(path, bytes(dataset.to_netcdf(engine="h5netcdf", encoding=encoding)))


def write_jacobians(path, checkpoints: dict[str, str], config: dict) -> None:
    """Panel h, each decoder's Jacobian images at rest (a job of :func:`run_into`)."""
    figures.save(figures.jacobian_images({kind: jacobian_pair(kind, checkpoints[kind], config)
                                          for kind in checkpoints}), path)


def write_animation(path, trial, measures: dict[str, np.ndarray], resolution: int) -> None:
    """The animation of one trial, from its ``measures[key]`` per step (a job of :func:`run_into`)."""
    balls = np.stack([measures["ball_x_m"], measures["ball_y_m"]], axis=1)
    mu = np.stack([measures["mu_shoulder_deg"], measures["mu_elbow_deg"]], axis=1)
    atomic_write(path, gif_bytes(frames(mu, rubber_pose(trial.offset_x), balls, resolution)))
