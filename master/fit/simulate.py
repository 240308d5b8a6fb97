"""Simulated participants on the sweep machinery: prior (or posterior) draws as sweep points, their trials run
in lockstep batches of several participants, resumably, and read back as summary statistics.

One simulated participant is one draw of the fitted parameters with its own master seed (its own tactile
delays), run over every design cell of the data (``fit.trials_per_cell`` trials each). Its summary statistics
are, per cell and measure, the mean of the trials' final values, cell-major as in
:meth:`rhi.master.fit.data.Data.statistic_names`. The trials of ``fit.participants_per_batch`` consecutive
participants share one lockstep batch (:func:`rhi.master.sweeps.plan.build`): their parameters differ per trial.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rhi.master.config.schedules import trial_length
from rhi.master.fit.data import EVENT_TIMES, Data, percentile_of, spread_of
from rhi.master.fit.plan import FitPlan, simulation_seed
from rhi.master.sweeps import plan as sweeps


def participant_points(plan: FitPlan, inference_values: np.ndarray, stream: str) -> list[dict]:
    """One sweep point per row of ``inference_values`` (draws in the inference space): the parameters'
    values in their own units and the participant's master seed."""
    points = []
    for number, row in enumerate(inference_values):
        point = {p.key: float(p.from_inference(value)) for p, value in zip(plan.parameters, row)}
        point["experiment.seed"] = simulation_seed(plan.settings["seed"], number, stream)
        points.append(point)
    return points


def participants_sweep(plan: FitPlan, inference_values: np.ndarray, stream: str) -> sweeps.Sweep:
    """The sweep that simulates these participants (checked, planned; nothing runs)."""
    return sweeps.build(plan.base, participant_points(plan, inference_values, stream),
                        workers=plan.settings["workers"],
                        points_per_batch=plan.settings["participants_per_batch"])


def simulate(sweep: sweeps.Sweep, out: Path, client, label: str, replace: bool = False) -> tuple[dict[str, dict], int]:
    """Run the sweep's missing trials into ``out`` (a sweep folder) on ``client()`` (a callable giving a checked
    dask Client); (every record by trial id, trials run now). replace: a different sweep in ``out`` is
    replaced, keeping the trials the two share (the posterior predictive's draws follow the data)."""
    from rhi.master.runtime.context import RunContext
    from rhi.master.sweeps.run import run_into

    return run_into(sweep, sweeps.resolve_task(sweep.task), out, RunContext(force=replace), label=label, plots=False,
                    client=client)


class Pool:
    """One dask Client for a fit's sweeps, started on first use (a rerun with nothing missing starts none) and
    closed with the fit: a callable giving it, checked (the workers import this package)."""

    def __init__(self, scheduler: str | None, workers: int | None, debug: bool):
        from contextlib import ExitStack

        self.scheduler, self.workers, self.debug, self.stack, self.client = scheduler, workers, debug, ExitStack(), None

    def __call__(self):
        if self.client is None:
            from rhi.master.sweeps.plan import DEFAULT_TASK
            from rhi.master.sweeps.runner import check_workers, dask_client

            self.client = self.stack.enter_context(dask_client(self.scheduler, self.workers, self.debug))
            check_workers(self.client, DEFAULT_TASK)
        return self.client

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return self.stack.__exit__(*exc)


def statistics(sweep: sweeps.Sweep, records: dict[str, dict], data: Data, measures: list[str]) -> np.ndarray:
    """(participants, cells x measures): each simulated participant's cell means, NaN where a trial failed.

    A group's statistics, each trial one participant of the simulated study (a ``[population]``): a spread
    (``drift_cm_sd``, :func:`rhi.master.fit.data.spread_of`) is the sample sd (ddof 1) of the measure over the cell's
    trials, a percentile (``ownership_onset_s_q90``) numpy's linear one (Hyndman & Fan type 7). An event's time
    (:data:`rhi.master.fit.data.EVENT_TIMES`) that a participant never reached within the trial is beyond its end:
    its mean is over the participants who reached it (NaN if none did), its percentiles count the others as the
    trial's length (exact wherever the percentile falls before the end, as a reported one does)."""
    cells = {cell: n for n, cell in enumerate(data.cells)}
    bases = [spread_of(m) or m for m in measures]
    values = np.full((len(sweep.points), len(data.cells), len(measures)), None, dtype=object)
    for trial in sweep.trials:
        cell = cells.get((trial.condition, trial.stimulation))
        if cell is None:  # a cell of the full cross that the data lack
            continue
        record = records.get(trial.id)
        failed = record is None or record.get("status") != "ok"
        for position, base in enumerate(bases):
            found = values[trial.point, cell, position] or []
            if failed:
                value = np.nan
            elif base in EVENT_TIMES and np.isnan(record["outcome"][base]):
                value = np.inf  # never within the trial
            else:
                value = record["outcome"][base]
            values[trial.point, cell, position] = [*found, value]
    percentiles = [percentile_of(m) for m in measures]
    result = np.full(values.shape, np.nan)
    for index in np.ndindex(values.shape):
        given = np.asarray(values[index] or [np.nan], dtype=float)
        percentile = percentiles[index[2]]
        if np.isinf(given).any() and percentile is not None:
            given = np.minimum(given, trial_length(sweep.configs[index[0]]))
        elif np.isinf(given).any():  # an event's mean or sd: over the participants who reached it
            given = given[np.isfinite(given) | np.isnan(given)]
        if given.size == 0:
            continue
        if percentile is not None:
            result[index] = np.quantile(given, percentile / 100.0)
        elif bases[index[2]] != measures[index[2]]:  # a spread: the sample sd
            result[index] = given.std(ddof=1) if given.size > 1 else np.nan
        else:  # summed in trial order, then divided: the bits of the sums this function always made
            result[index] = sum(given.tolist()) / given.size
    return result.reshape(len(sweep.points), -1)


def with_noise(values: np.ndarray, data: Data, measures: list[str], noise: dict[str, float], seed: int,
               stream: str) -> np.ndarray:
    """``values`` plus the observation noise: a normal on each cell mean of sd the data's ``MEASURE_sem`` for that
    cell where the data give it, else ``noise[measure]`` (:meth:`rhi.master.fit.data.Data.noise_sd`), drawn from the
    fit's seed and the stream's name (the same seed, the same noise)."""
    sd = data.noise_sd(measures, noise)
    if not sd.any():
        return values
    rng = np.random.default_rng([seed, 1, sum(map(ord, stream))])
    return values + rng.standard_normal(values.shape) * sd
