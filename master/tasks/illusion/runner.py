"""The rubber-hand experiment: the protocol in lockstep batches, one per decoder, failures isolated.

One batch per decoder: every condition x stimulation x trial of that decoder advances together
(the batch dimension), so one decoder call serves them all; the decoders' batches run side by side,
each in its own process (:mod:`rhi.master.runtime.pool`).
"""
from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from rhi.master import models
from rhi.master.cosim import SimulationError
from rhi.master.tasks.illusion.measures import end_of_trial, measures
from rhi.master.runtime.context import RunContext
from rhi.master.runtime.pool import JOB_THREADS, Workers, process_count, run_jobs
from rhi.master.config.protocol import Trial, make_trial, plan
from rhi.master.tasks.illusion.wiring import run_batch

log = logging.getLogger("rhi.experiment")


def without_failures(run_trials, trials: list[Trial]):
    """``run_trials(trials)``, dropping any trial a component blames for a failed step.

    A component that names the failing trials (``StepFailure(trials=...)``, e.g. the FMU adapter on a
    NaN) costs only those: they are recorded and the rest of the batch is run again from the start,
    which gives them exactly the numbers they would have had (trials are independent). A failure
    that names no trial stops the run (the error carries ``.failures``, the trials blamed before it).
    Returns (result or None, kept trials, {trial: error}).
    """
    failures: dict[Trial, str] = {}
    while trials:
        try:
            return run_trials(trials), trials, failures
        except SimulationError as error:
            if not error.trials:
                error.failures = failures
                raise
            for position in error.trials:
                failures[trials[position]] = str(error)
            trials = [t for position, t in enumerate(trials) if position not in error.trials]
    return None, trials, failures


def run(config: dict, checkpoints: dict[str, str], body: str | None = None, context: RunContext | None = None,
        fast: dict[str, bool] | None = None, workers: Workers | None = None):
    """Every trial of the protocol, one lockstep batch per decoder, the batches side by side (the decoders on
    ``context.device``; on a GPU the batches run one after the other).

    body: an FMU to use as the body (None: the native plant). context: progress bars, the device, and
    ``processes``, the most batches at once (default: the usable cores; 1: one after the other, here); the
    numbers do not depend on it. workers: run the batches on these (left open) instead of workers of their own.
    fast: per decoder, whether it runs in the fast mode (default: ``decoder.fast`` for all).
    Returns (trials, times, per_step, seconds, failures): ``per_step[key]`` has shape
    (steps + 1, n_trials) in the order of ``trials`` (the protocol's order, less any failed trial);
    ``seconds`` maps each decoder to its batches' wall time (summed); ``failures`` maps each failed trial to
    its error.
    """
    context = context or RunContext()
    progress, processes, device = context.progress, context.processes, context.device
    kinds = config["experiment"]["decoders"]
    fast = fast or {kind: config["decoder"]["fast"] for kind in kinds}
    batches = lockstep_batches(config)
    if device != "cpu":  # one GPU: the batches one after the other
        processes, workers = 1, None
    jobs = [(BatchJob(config, batch[0].decoder, checkpoints[batch[0].decoder], batch, body, position,
                      fast[batch[0].decoder], device),)
            for position, batch in zip(bar_positions(len(batches), progress, processes, workers), batches)]
    kept, blocks, seconds, failures, times = [], [], {}, {}, None
    for trials, (batch, result, spent, failed) in zip(batches, run_jobs(decoder_batch, jobs, processes, workers)):
        seconds[trials[0].decoder] = seconds.get(trials[0].decoder, 0.0) + spent
        failures.update(failed)
        log.debug(f"{trials[0].decoder} trials x{len(trials)}: {config['experiment']['steps']} steps in {spent:.1f} s"
                  f"{f', {len(failed)} failed' if failed else ''}")
        if result is not None:
            kept += batch
            blocks.append(result["measures"])
            times = result["times"]
    if not blocks:
        reasons = sorted(set(failures.values())) or ["the protocol has no trial"]
        raise SimulationError("experiment", 0.0, "every trial failed: " + "; ".join(reasons))
    per_step = {key: np.concatenate([block[key] for block in blocks], axis=1) for key in blocks[0]}
    return kept, times, per_step, seconds, failures


def lockstep_batches(config: dict) -> list[list[Trial]]:
    """The protocol cut into lockstep batches: each decoder's trials in the protocol's order, in batches of
    ``experiment.batch_trials`` (0: one batch per decoder); the cut depends on the configuration alone."""
    size = config["experiment"]["batch_trials"]
    batches = []
    for kind in config["experiment"]["decoders"]:
        mine = [trial for trial in plan(config) if trial.decoder == kind]
        batches += [mine[start:start + (size or len(mine))] for start in range(0, len(mine), size or len(mine))]
    return batches


@dataclass(frozen=True)
class BatchJob:
    """One lockstep batch of one decoder's trials, as :func:`run` hands it to a worker.

    Attributes
    ----------
    config : dict
        The run's configuration.
    kind, checkpoint : str
        The decoder slot and its checkpoint file.
    trials : list of Trial
        The batch's trials, in the protocol's order.
    body : str or None
        An FMU to use as the body (None: the native plant).
    progress : int or None
        The line of this batch's progress bar (None: no bar).
    fast : bool or None
        Whether the decoder runs in the fast mode (None: ``decoder.fast``).
    device : str
        Where the decoder runs.
    """

    config: dict
    kind: str
    checkpoint: str
    trials: list
    body: str | None = None
    progress: int | None = None
    fast: bool | None = None
    device: str = "cpu"


def decoder_batch(job: BatchJob):
    """One lockstep batch of one decoder's trials, a failing trial dropped and recorded (a job of :func:`run`).

    Returns (kept trials, {"times", "measures"} or None, seconds, {failed trial: error}).
    """
    from rhi.master.decoders.cache import decoder_component  # torch is imported only when a run needs it

    config, kind, checkpoint, trials, body, progress = (job.config, job.kind, job.checkpoint, job.trials, job.body,
                                                        job.progress)
    fast, device = job.fast, job.device
    make_body = body_factory(body, config)[0]

    def run_trials(batch):
        with step_bar(f"{kind} trials x{len(batch)}", config["experiment"]["steps"], progress) as update:
            return run_batch(decoder_component(kind, checkpoint, config, fast, JOB_THREADS, device), batch, config,
                             make_body() if make_body else None, update)

    began = time.perf_counter()
    try:
        result, kept, failed = without_failures(run_trials, trials)
    except SimulationError as error:  # blames no trial: this decoder's remaining trials all fail with it
        failed = dict(error.failures)
        failed.update({t: str(error) for t in trials if t not in failed})
        result, kept = None, []
    outcome = None if result is None else {"times": result.times, "measures": measures(result, models.of(config))}
    return kept, outcome, time.perf_counter() - began, failed


def body_factory(path, config: dict | None = None):
    """A callable making the body component (None: the native plant) and the body's parameter names.

    ``path``: a registered body variant's name (``rhi.master.config.bodies.VARIANTS``: ``batched``, ``kinematic``, run
    in this process), or an FMU, checked now, before any work: the body contract (every problem listed) and that
    its binary loads. Its calls are limited to ``[fmu] step_timeout_s`` seconds each (0: no limit). None: the body
    ``config`` chooses (``experiment.body``).
    """
    from rhi.master.config.bodies import configured, variant_class

    if path is None and config is not None:
        path = configured(config)
    if path is None:
        return None, None

    made = variant_class(path)
    if made is not None:
        return made, set(made().variables)
    from rhi.components.body.contract import BODY_CONTRACT
    from rhi.components.fmu import FMUComponent

    limit = (config or {}).get("fmu", {}).get("step_timeout_s") or None
    probe = FMUComponent(path, "body", BODY_CONTRACT, step_timeout=limit)
    return (lambda: FMUComponent(path, "body", BODY_CONTRACT, step_timeout=limit)), set(probe.variables)


def trial_outcome(config: dict, decoder: str, condition: str, stimulation: str, index: int,
                  checkpoint: str | None = None) -> dict:
    """Run ONE trial and return its end-of-trial values (a batch of one, :func:`batch_outcomes`).

    The decoder checkpoint is ``checkpoint`` or the one the configuration names or caches; it must
    exist already (sweeps train nothing on the workers). A failed trial raises a RuntimeError
    carrying its record's error.
    """
    record, = batch_outcomes(config, decoder, [make_trial(config, decoder, condition, stimulation, index)],
                             checkpoint)
    if record["status"] != "ok":
        raise RuntimeError(record["error"])
    return record["outcome"]


def batch_outcomes(config: dict, decoder: str, trials: list[Trial], checkpoint: str | None = None) -> list[dict]:
    """Run ``trials`` (all of ``decoder``) in ONE lockstep batch; one record per trial, in their order.

    A record is ``{"status": "ok", "outcome": {...}}`` (drift_cm, force_n, gamma_final, seed and every
    other end-of-trial value) or ``{"status": "failed", "error": "Type: message", "traceback": ...}``.
    Failures are isolated per trial and never raised: a trial a component blames (``StepFailure``
    naming it) is recorded alone and the rest rerun without it (:func:`without_failures`); a failure
    that blames no trial reruns each remaining trial alone, a batch of one, so that only the trials
    that fail by themselves are recorded as failed. The same trials in the same order always take the
    same path, so they always get the same numbers.
    """
    import traceback

    from rhi.master.decoders.cache import checkpoint_path, decoder_component

    make_body = body_factory(None, config)[0]  # the configuration's body (experiment.body)

    def run_trials(batch: list[Trial]) -> list[dict]:
        path = checkpoint or checkpoint_path(decoder, config, must_exist=True)
        # one torch thread, as in the experiment's batches: the same numbers, and sweep workers are one core each
        result = run_batch(decoder_component(decoder, path, config, threads=JOB_THREADS), batch, config,
                           make_body() if make_body else None)
        final = end_of_trial(result.times, measures(result, models.of(config)), config["experiment"]["probe_times"])
        renamed = {"drift_cm": "drift_cm", "force_x_n": "force_n", "gamma": "gamma_final"}
        return [{"status": "ok", "outcome": {
            **{name: float(final[key][column]) for key, name in renamed.items()}, "seed": trial.seed,
            **{key: float(values[column]) for key, values in final.items() if key not in renamed}}}
            for column, trial in enumerate(batch)]

    records: dict[Trial, dict] = {}
    waiting = [list(trials)]  # batches still to run: the whole, then (after a failure blaming no trial) singles
    while waiting:
        batch = waiting.pop(0)
        try:
            result, kept, blamed = without_failures(run_trials, batch)
        except Exception as error:  # noqa: BLE001: any failure of a trial is data, not a crash
            blamed, kept, result = dict(getattr(error, "failures", {})), [], None
            rest = [t for t in batch if t not in blamed]
            if len(batch) == 1:
                records[batch[0]] = failed_record(type(error).__name__, str(error), traceback.format_exc())
            else:
                waiting += [[t] for t in rest]
        records.update({t: failed_record("SimulationError", reason) for t, reason in blamed.items()})
        records.update(zip(kept, result or []))
    return [records[t] for t in trials]


def failed_record(kind: str, message: str, trace: str = "") -> dict:
    """The record of a failed trial: ``{"status": "failed", "error": "Kind: message" (on one line),
    "traceback": trace}``."""
    message = " ".join(message.split()) or "(no message)"
    return {"status": "failed", "error": f"{kind}: {message}", "traceback": trace}


def bar_positions(jobs: int, progress: bool, processes: int | None = None,
                  workers: Workers | None = None) -> list[int | None]:
    """The terminal line of each job's progress bars (:func:`step_bar`): a line each when the jobs run side by
    side (on ``workers``, else on up to ``processes``), line 0 when they run in turn; None each without
    ``progress``."""
    if not progress:
        return [None] * jobs
    side_by_side = process_count(jobs, workers.processes if workers else processes) > 1
    return [position if side_by_side else 0 for position in range(jobs)]


@contextmanager
def step_bar(description: str, total: int, position: int | None):
    """A progress bar of ``total`` steps on line ``position`` of the terminal, removed when done; yields its
    ``update(done, total)`` callback for :func:`rhi.master.tasks.illusion.wiring.run_batch` (None, and no bar,
    when ``position`` is None)."""
    if position is None:
        yield None
        return
    from rhi.master.runtime.progress import bar

    with bar(total=total, desc=description, unit="step", leave=False, position=position) as shown:
        yield lambda done, _total: shown.update(done - shown.n)
