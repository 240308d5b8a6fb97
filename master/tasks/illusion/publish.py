"""The experiment in memory (:func:`run_experiment`) and into a folder (:func:`run_into`, ``rhi experiment``):
train what is missing, run the protocol, write every result file.

DIR is written in a staging folder beside it and renamed into place when complete
(:mod:`rhi.master.outputs.files`), so it holds either a whole run or nothing from this one.
"""
from __future__ import annotations

import json
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
from rhi.master.config import bodies, population
from rhi.master.config.protocol import plan, rubber_pose
from rhi.master.outputs import cohort, figures, tables
from rhi.master.outputs.files import atomic_write, check_output, output_folder
from rhi.master.outputs.provenance import package_versions
from rhi.master.outputs.animation import frames, gif_bytes

log = logging.getLogger("rhi.experiment")


@dataclass
class ExperimentResult:
    """The protocol's run, in memory: what ``rhi experiment`` writes into DIR, before it is written.

    Attributes
    ----------
    config : dict
        The configuration it ran.
    trials : list of Trial
        The trials that ran to the end, in the protocol's order (failed ones left out: ``failures``).
    times : numpy.ndarray
        (steps + 1,) s.
    per_step : dict of str to numpy.ndarray
        Each measure per step and trial, (steps + 1, len(trials)) (:func:`rhi.master.tasks.illusion.measures.measures`).
    final : dict of str to numpy.ndarray
        Each measure at the end of the trial, (len(trials),).
    summary : list of list
        The rows of summary.csv (columns ``rhi.master.outputs.tables.summary_columns``).
    failures : dict
        Each failed trial and its error.
    provenance : dict
        What run.json records: the model, the body, checkpoints, fast-mode verdicts, seeds, versions, timings.
    began : float
        ``time.perf_counter()`` when the run began (run.json's total time runs from it).
    """

    config: dict
    trials: list
    times: np.ndarray
    per_step: dict
    final: dict
    summary: list
    failures: dict
    provenance: dict = field(default_factory=dict)
    began: float = 0.0

    def write(self, out, force: bool = False) -> None:
        """Publish DIR = ``out`` as ``rhi experiment`` does: whole or not at all (a staging folder renamed)."""
        check_output(out, force)
        with output_folder(out, force) as staging, Workers() as workers:
            self.write_files(staging, workers)

    def write_files(self, staging, workers: Workers) -> None:
        """summary.csv, trials.csv, figures/ and run.json into the folder ``staging``, the files on ``workers``."""
        trials, per_step, config = self.trials, self.per_step, self.config
        columns = tables.summary_columns(config["experiment"]["probe_times"])
        measures = cohort_measures(config)
        header = columns + cohort.columns(measures, columns)
        atomic_write(staging / "summary.csv", tables.csv_text(header, self.summary))
        (staging / "figures").mkdir()
        if measures:
            write_participants(staging / "participants.csv", config)
            cohort.write_strip_figure(staging / "figures" / "cohort.png", trials, self.final,
                                      [*cohort.STRIPS, *models.of(config).measures])
        shown = next((i for i, t in enumerate(trials) if (t.condition, t.stimulation) == ("left", "sync")), 0)
        name = f"trial_{trials[shown].decoder}_{trials[shown].condition}_{trials[shown].stimulation}.gif"
        animated = {key: per_step[key][:, shown] for key in ANIMATED}
        checkpoints = self.provenance["checkpoints"]
        workers.map(call, [  # the files, side by side on the workers the run started (else here), the longest first
            (write_trials, staging / "trials.csv", trials, self.times, per_step),
            (write_jacobians, staging / "figures" / "h_jacobians.png", checkpoints, config),
            (write_animation, staging / "figures" / name, trials[shown], animated, config["experiment"]["resolution"]),
            *figures.panel_jobs(staging / "figures", trials, self.times, per_step, self.final, None)], start=False)
        provenance = {**self.provenance, "figures": sorted(path.name for path in (staging / "figures").iterdir())}
        log.debug(f"wrote summary.csv, trials.csv and {len(provenance['figures'])} figures into {staging}")
        provenance["timings_s"] = {**provenance["timings_s"], "total": time.perf_counter() - self.began}
        atomic_write(staging / "run.json", json.dumps(provenance, indent=2, default=str) + "\n")


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
    from rhi.master import config as configuration

    began = time.perf_counter()
    config = configuration.load() if config is None else config
    context = context or RunContext()
    body = body if body is not None else bodies.configured(config)  # --body, else experiment.body
    declared = checked_before_work(config, body, context.device)
    if workers is None:
        with Workers(1 if context.device != "cpu" else context.processes) as own:
            result = simulate_protocol(config, body, context, own, declared)
    else:
        result = simulate_protocol(config, body, context, workers, declared)
    result.began = began
    return result


def checked_before_work(config: dict, body: str | None, device: str):
    """What can be checked before any training or run: the decoders' checkpoints or training settings (and the
    model's pose encoders), the body FMU; returns the body's parameter names (None: the native plant)."""
    check_decoders(config, device)
    return body_factory(body, config)[1]


def simulate_protocol(config: dict, body: str | None, context: RunContext, workers: Workers, declared):
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
        "schema_version": tables.SCHEMA_VERSION,
        "command": "rhi experiment", "model": models.of(config).name,
        "configuration": config, "body": body or "native pymunk plant",
        "body_keys_not_declared": sorted(f"body.{key}" for key in config["body"]
                                         if declared is not None and key not in declared),
        "checkpoints": checkpoints, "fast_mode": modes, "device": context.device,
        "seeds": {"master": config["experiment"]["seed"], "trials": [t.__dict__ for t in trials]},
        "versions": package_versions(),
        "timings_s": {"training": training_seconds, "fast_check": check_seconds, "trials": run_seconds},
        "failed_trials": [{**trial.__dict__, "error": error} for trial, error in failures.items()],
    }
    return ExperimentResult(config, trials, times, per_step, final, summary, failures, provenance)


def run_into(out, config: dict, body: str | None = None, context: RunContext | None = None) -> dict:
    """Run the protocol of ``config`` and write DIR = ``out``; returns {failed trial: error}.

    body: an FMU to use as the body (None: the native pymunk plant). context: force (replace DIR of rhi's),
    progress, device (where the decoders train and run: cpu, cuda; resolved). Everything that can be checked is
    checked before the staging folder exists and before any training: the output folder, the decoders'
    checkpoints (kind, resolution, camera) or training settings, the body FMU.
    """
    began, context = time.perf_counter(), context or RunContext()
    check_output(out, context.force)
    declared = checked_before_work(config, body, context.device)
    with output_folder(out, context.force) as staging, Workers(1 if context.device != "cpu" else None) as workers:
        result = simulate_protocol(config, body, context, workers, declared)
        result.began = began
        result.write_files(staging, workers)
    return result.failures


def cohort_measures(config: dict) -> dict[str, str]:
    """The measures whose between-participant statistics summary.csv appends (:mod:`rhi.master.outputs.cohort`):
    none unless the configuration's population varies, so that a run without one keeps its bytes."""
    if not population.varies(config):
        return {}
    return cohort.measures_of(tuple(models.of(config).measures),
                              tuple(tables.probe_measures(config["experiment"]["probe_times"])))


def write_participants(path, config: dict) -> None:
    """participants.csv: every participant the protocol plans (``experiment.trials``), with its drawn values."""
    indices = range(config["experiment"]["trials"])
    seeds = [population.participant_seed(config["experiment"]["seed"], index) for index in indices]
    atomic_write(path, cohort.participants_csv(indices, seeds, population.cohort(config, indices)))


ANIMATED = ("ball_x_m", "ball_y_m", "mu_shoulder_deg", "mu_elbow_deg")  # the measures the animation shows


def write_trials(path, trials, times, per_step) -> None:
    """trials.csv (a job of :func:`run_into`)."""
    atomic_write(path, tables.trials_csv(trials, times, per_step))


def write_jacobians(path, checkpoints: dict[str, str], config: dict) -> None:
    """Panel h, each decoder's Jacobian images at rest (a job of :func:`run_into`)."""
    figures.save(figures.jacobian_images({kind: jacobian_pair(kind, checkpoints[kind], config)
                                          for kind in checkpoints}), path)


def write_animation(path, trial, measures: dict[str, np.ndarray], resolution: int) -> None:
    """The animation of one trial, from its ``measures[key]`` per step (a job of :func:`run_into`)."""
    balls = np.stack([measures["ball_x_m"], measures["ball_y_m"]], axis=1)
    mu = np.stack([measures["mu_shoulder_deg"], measures["mu_elbow_deg"]], axis=1)
    atomic_write(path, gif_bytes(frames(mu, rubber_pose(trial.offset_x), balls, resolution)))
