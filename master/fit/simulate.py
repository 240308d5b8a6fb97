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
from rhi.master.fit.columns import EVENT_TIMES, correlation_of, measures_of, percentile_of
from rhi.master.fit.data import Data
from rhi.master.fit.plan import FitPlan, simulation_seed
from rhi.master.sweeps import plan as sweeps


def participant_points(plan: FitPlan, inference_values: np.ndarray, stream: str) -> list[dict]:
    """One sweep point per row of ``inference_values`` (draws in the inference space): the parameters'
    values in their own units and the participant's master seed. A fit of several protocols has one point per
    protocol and row, protocol by protocol, each protocol's with its design's keys and its own seed (another
    group of people)."""
    points = []
    for part, keys in enumerate(plan.designs or [{}]):
        named = f"{stream}/protocol {part}" if plan.designs else stream
        protocol = plan.protocols[part] if plan.designs else ""
        for number, row in enumerate(inference_values):
            point = {**keys, **{p.config_key: float(p.from_inference(value))  # a protocol's own: in it alone
                                for p, value in zip(plan.parameters, row) if p.protocol in ("", protocol)}}
            point["experiment.seed"] = simulation_seed(plan.settings["seed"], number, named)
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


def simulated_statistics(plan: FitPlan, sweep: sweeps.Sweep, records: dict[str, dict], data: Data,
                         stream: str) -> np.ndarray:
    """(draws, cells x measures): the statistics a fit compares with the data's, each participant's own measurement
    error (``fit.participant_noise``) and each cell mean's observation noise (``fit.noise``, the data's
    ``MEASURE_sem``) included, drawn from the fit's seed and ``stream``."""
    own = participant_errors(sweep, plan.participant_noise, plan.settings["seed"], stream)
    return with_noise(statistics(sweep, records, data, plan.measures, own), data, plan.measures, plan.noise,
                      plan.settings["seed"], stream)


def participant_errors(sweep: sweeps.Sweep, noise: dict[str, float], seed: int, stream: str) -> dict[str, dict]:
    """Measure -> {trial id: a normal error of sd ``noise[measure]``}: each simulated participant's own measurement
    error in each cell (a pointing's), one draw per trial in the sweep's order from numpy's
    ``default_rng([seed, 2, stream's code, measure's code])``; empty without ``fit.participant_noise``."""
    errors = {}
    for measure, sd in sorted(noise.items()):
        rng = np.random.default_rng([seed, 2, sum(map(ord, stream)), sum(map(ord, measure))])
        errors[measure] = dict(zip((t.id for t in sweep.trials), sd * rng.standard_normal(len(sweep.trials))))
    return errors


def statistics(sweep: sweeps.Sweep, records: dict[str, dict], data: Data, measures: list[str],
               errors: dict[str, dict] | None = None) -> np.ndarray:
    """(draws, cells x measures): each simulated participant's (or study's) statistics, NaN where a trial failed.

    A group's statistics, each trial one participant of the simulated study (a ``[population]``): a spread
    (``drift_cm_sd``, :func:`rhi.master.fit.columns.spread_of`) is the sample sd (ddof 1) of the measure over the cell's
    trials, a percentile (``ownership_onset_s_q90``) numpy's linear one (Hyndman & Fan type 7), a correlation
    (``r_drift_cm_vs_force_n``) Pearson's r of the two over the cell's participants. A contrast's cell
    (``sync-async``) takes each participant's difference of the two stimulations first. An event's time
    (:data:`rhi.master.fit.columns.EVENT_TIMES`) that a participant never reached within the trial is beyond its end:
    its mean is over the participants who reached it (NaN if none did), its percentiles count the others as the
    trial's length (exact wherever the percentile falls before the end, as a reported one does). Several
    protocols' statistics follow one another, as the data's cells do. ``errors``: measure -> {trial id: error}
    added to each participant's value first (:func:`participant_errors`)."""
    parts = data.designs()
    draws = len(sweep.points) // len(parts)
    bases = [measures_of(m) for m in measures]
    outcomes: dict[tuple, dict[int, float]] = {}  # (point, condition, stimulation, measure) -> trial index -> value
    for trial in sweep.trials:
        record = records.get(trial.id)
        failed = record is None or record.get("status") != "ok"
        for base in set().union(*bases):
            value = np.nan if failed else record["outcome"][base]
            if errors and base in errors:
                value = value + errors[base][trial.id]
            if base in EVENT_TIMES and not failed and np.isnan(value):
                value = np.inf  # never within the trial
            outcomes.setdefault((trial.point, trial.condition, trial.stimulation, base), {})[trial.index] = value
    percentiles = [percentile_of(m) for m in measures]
    result = np.full((draws, len(data.cells), len(measures)), np.nan)
    cell = 0
    for number, part in enumerate(parts):
        for condition, named in part.cells:
            for draw in range(draws):
                point = number * draws + draw
                stimulations = part.contrasts.get(named, (named,))
                for position, measure in enumerate(measures):
                    values = [cell_values(outcomes, point, condition, stimulations, base) for base in bases[position]]
                    result[draw, cell, position] = correlation(*values) if correlation_of(measure) else cell_statistic(
                        values[0], percentiles[position], bases[position][0] != measure,
                        trial_length(sweep.configs[point]))
            cell += 1
    return result.reshape(draws, -1)


def cell_values(outcomes: dict, point: int, condition: str, stimulations: tuple, measure: str) -> np.ndarray:
    """One cell's value of each participant, in trial order: a stimulation's, or a contrast's two subtracted
    participant by participant (inf - inf, an event neither reached, is NaN: no difference known)."""
    found = [outcomes.get((point, condition, s, measure), {}) for s in stimulations]
    if len(found) == 1:
        return np.array([found[0][k] for k in sorted(found[0])] or [np.nan], dtype=float)
    with np.errstate(invalid="ignore"):
        return np.array([found[0][k] - found[1].get(k, np.nan) for k in sorted(found[0])] or [np.nan], dtype=float)


def correlation(first: np.ndarray, second: np.ndarray) -> float:
    """Pearson's r of two measures over a cell's participants (those with both finite, the same trials); NaN for
    fewer than 3 or a measure that does not vary."""
    both = np.isfinite(first) & np.isfinite(second)
    if both.sum() < 3:
        return np.nan
    a, b = first[both] - first[both].mean(), second[both] - second[both].mean()
    scale = float(np.sqrt((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / scale) if scale > 0 else np.nan


def cell_statistic(given: np.ndarray, percentile: int | None, spread: bool, length: float) -> float:
    """A cell's statistic of its participants' values: their percentile, sample sd or mean (module notes)."""
    if np.isinf(given).any() and percentile is not None:
        given = np.minimum(given, length)
    elif np.isinf(given).any():  # an event's mean or sd: over the participants who reached it
        given = given[np.isfinite(given) | np.isnan(given)]
    if given.size == 0:
        return np.nan
    if percentile is not None:
        return float(np.quantile(given, percentile / 100.0))
    if spread:  # the sample sd
        return float(given.std(ddof=1)) if given.size > 1 else np.nan
    return sum(given.tolist()) / given.size  # summed in trial order, then divided: the bits this function always made


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
