"""The rubber-hand experiment: the protocol in lockstep batches, one per decoder, failures isolated.

One batch per decoder: every condition x stimulation x trial of that decoder advances together
(the batch dimension), so one decoder call serves them all.
"""
from __future__ import annotations

import time

import numpy as np

from master.cosim import SimulationError
from master.experiment.measures import end_of_trial, measures
from master.experiment.protocol import Trial, make_trial, plan
from master.experiment.wiring import run_batch


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


def run(config: dict, checkpoints: dict[str, str], body_factory=None, progress: bool = False, device: str = "cpu"):
    """Every trial of the protocol, one lockstep batch per decoder (the decoders on ``device``).

    Returns (trials, times, per_step, seconds, failures): ``per_step[key]`` has shape
    (steps + 1, n_trials) in the order of ``trials`` (the protocol's order, less any failed trial);
    ``failures`` maps each failed trial to its error.
    """
    from master.experiment.decoders import decoder_component  # torch is imported only when a run needs it

    kept, blocks, seconds, failures, times = [], [], {}, {}, None
    protocol = plan(config)
    for kind in config["experiment"]["decoders"]:
        def run_trials(batch, kind=kind):
            bar = progress_bar(f"{kind} trials x{len(batch)}", config["experiment"]["steps"]) if progress else None
            body = body_factory() if body_factory else None
            try:
                return run_batch(decoder_component(kind, checkpoints[kind], config, device), batch, config, body,
                                 bar.update_to if bar else None)
            finally:
                if bar:
                    bar.close()

        began = time.perf_counter()
        mine = [t for t in protocol if t.decoder == kind]
        try:
            result, batch, failed = without_failures(run_trials, mine)
        except SimulationError as error:  # blames no trial: this decoder's remaining trials all fail with it
            failed = dict(error.failures)
            failed.update({t: str(error) for t in mine if t not in failed})
            result, batch = None, []
        seconds[kind] = time.perf_counter() - began
        failures.update(failed)
        if result is not None:
            kept += batch
            blocks.append(measures(result))
            times = result.times
    if not blocks:
        reasons = sorted(set(failures.values())) or ["the protocol has no trial"]
        raise SimulationError("experiment", 0.0, "every trial failed: " + "; ".join(reasons))
    per_step = {key: np.concatenate([block[key] for block in blocks], axis=1) for key in blocks[0]}
    return kept, times, per_step, seconds, failures


def trial_outcome(config: dict, decoder: str, condition: str, stimulation: str, index: int,
                  checkpoint: str | None = None) -> dict:
    """Run ONE trial (a sweep's task) and return its end-of-trial values.

    The decoder checkpoint is ``checkpoint`` or the one the configuration names or caches; it must
    exist already (sweeps train nothing on the workers).
    """
    from master.experiment.decoders import checkpoint_path, decoder_component

    trial = make_trial(config, decoder, condition, stimulation, index)
    path = checkpoint or checkpoint_path(decoder, config, must_exist=True)
    result = run_batch(decoder_component(decoder, path, config), [trial], config)
    final = {key: float(value[0]) for key, value in end_of_trial(result.times, measures(result)).items()}
    return {"drift_cm": final["drift_cm"], "force_n": final["force_x_n"], "gamma_final": final["gamma"],
            "seed": trial.seed, **{k: v for k, v in final.items() if k not in ("drift_cm", "force_x_n", "gamma")}}


def progress_bar(description: str, total: int):
    from tqdm import tqdm

    bar = tqdm(total=total, desc=description, unit="step", leave=False)
    bar.update_to = lambda done, _total: bar.update(done - bar.n)
    return bar
