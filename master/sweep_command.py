"""`rhi sweep --config FILE [--scheduler ADDRESS] [--force] --out DIR`: run a sweep, resumably.

DIR holds sweep.json (the plan's fingerprint, points and configurations), trials/ID.json (one file
per finished trial, written atomically as it arrives), index.csv (one row per trial), summary.csv
(mean and sd per point and decoder x condition x stimulation) and figures/. Running the same
command again runs only the trials that have no successful record; a DIR holding a different
sweep is refused unless --force, which keeps only the trials the new sweep shares with it.
"""
from __future__ import annotations

import fcntl
import json
import logging
import os
import shutil
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from master import sweep as sweeps
from master.errors import ConfigError
from master.outputs import csv_text, number
from master.results import atomic_write, package_versions

MEASURES = ("drift_cm", "force_n", "gamma_final")  # what summary.csv and the figures show
NOT_MEASURES = ("seed",)  # numbers in an outcome that identify the trial rather than measure it
INDEX_EVERY_S = 2.0
MAX_LISTED = 50  # failures listed on the terminal; index.csv has all of them


def label(value) -> str:
    return value if isinstance(value, str) else json.dumps(value)


@contextmanager
def sweep_folder(out: Path, sweep: sweeps.Sweep, force: bool):
    """Check, lock and prepare DIR; yields the records already in it that belong to this sweep."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"output {out} exists and is not a folder")
    if not out.absolute().parent.is_dir():
        raise ConfigError(f"cannot write {out}: folder {out.absolute().parent} does not exist")
    manifest = out / "sweep.json"
    if out.is_dir() and not manifest.exists() and any(out.iterdir()) and not force:
        raise ConfigError(f"output folder {out} is not empty and holds no sweep (use --force to write into it)")
    out.mkdir(exist_ok=True)
    with open(out / ".lock", "w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ConfigError(f"another rhi sweep is writing to {out}") from None
        try:
            previous = json.loads(manifest.read_text()).get("fingerprint") if manifest.exists() else None
        except (OSError, ValueError):
            previous = "unreadable"
        if previous is not None and previous != sweep.fingerprint and not force:
            raise ConfigError(f"output folder {out} holds a different sweep (its file or the defaults changed); "
                              "use another --out, or --force to replace it")
        if previous != sweep.fingerprint:
            start_over(out, sweep)
        for leftover in (out / "trials").glob(".*.tmp"):  # a write cut short by a kill; its trial reruns
            leftover.unlink()
        yield read_records(out, sweep)


def start_over(out: Path, sweep: sweeps.Sweep) -> None:
    """Write the new manifest; drop every file of an older sweep except trials this one shares."""
    (out / "trials").mkdir(exist_ok=True)
    planned = {trial.id for trial in sweep.trials}
    for path in (out / "trials").glob("*.json"):
        if path.stem not in planned:
            path.unlink()
    for name in ("index.csv", "summary.csv"):
        (out / name).unlink(missing_ok=True)
    shutil.rmtree(out / "figures", ignore_errors=True)
    manifest = {"fingerprint": sweep.fingerprint, "task": sweep.task, "swept_keys": sweep.keys,
                "points": [{"point": n, "parameters": p, "configuration": c}
                           for n, (p, c) in enumerate(zip(sweep.points, sweep.configs))],
                "trials_planned": len(sweep.trials), "versions": package_versions()}
    atomic_write(out / "sweep.json", json.dumps(manifest, indent=1, sort_keys=True) + "\n")


def read_records(out: Path, sweep: sweeps.Sweep) -> dict[str, dict]:
    records = {}
    for trial in sweep.trials:
        path = out / "trials" / f"{trial.id}.json"
        try:
            records[trial.id] = json.loads(path.read_text())
        except (OSError, ValueError):  # missing; a torn file cannot happen with atomic writes
            continue
    return records


@contextmanager
def dask_client(scheduler: str | None, workers: int | None, debug: bool):
    """A Client on the given scheduler, or on a local pool of single-threaded worker processes."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, ValueError, TimeoutError) as error:
            raise ConfigError(f"cannot reach the Dask scheduler at {scheduler}: {error}") from None
        with client:
            yield client
        return
    quiet = False if debug else logging.ERROR
    # Only this machine: listen on loopback; the scheduler's small HTTP server on any free port.
    with LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                      host="127.0.0.1", dashboard_address=None, silence_logs=quiet,
                      scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}) as cluster, Client(cluster) as client:
        yield client


def check_workers(client, task: str) -> None:
    """Every connected worker must import the task's module (this package, installed there)."""
    if not client.scheduler_info().get("workers"):
        print(f"rhi sweep: waiting for a Dask worker to connect to {client.scheduler.address}", file=sys.stderr)
        client.wait_for_workers(1)
    module = task.partition(":")[0]
    for worker, answer in client.run(sweeps.worker_check, module, on_error="return").items():
        if isinstance(answer, BaseException):
            raise ConfigError(f"Dask worker {worker} cannot import {module} ({answer}); "
                              "install this package on every worker (see README, Sweeps)")


def prepare_decoders(sweep: sweeps.Sweep) -> None:
    """The experiment's trials load trained decoders; train any missing default here, once, never on
    the workers (a remote worker must see the same checkpoint paths, see README)."""
    if sweep.task != sweeps.DEFAULT_TASK:
        return
    from master.decoders import ensure_checkpoints

    for config in sweep.configs:  # a checkpoint already there is not trained again
        ensure_checkpoints(config)


def index_rows(sweep: sweeps.Sweep, records: dict[str, dict]) -> str:
    header = ["id", "point", *sweep.keys, "decoder", "condition", "stimulation", "trial", "seed", "status",
              *MEASURES, "elapsed_s", "error"]
    rows = []
    for trial in sweep.trials:
        record = records.get(trial.id)
        if record is None:
            continue
        outcome = record.get("outcome", {})
        rows.append([trial.id, trial.point, *(label(sweep.points[trial.point].get(k, "")) for k in sweep.keys),
                     trial.decoder, trial.condition, trial.stimulation, trial.index, trial.seed,
                     record["status"], *(repr(outcome[m]) if m in outcome else "" for m in MEASURES),
                     record.get("elapsed_s", ""), record.get("error", "")])
    return csv_text(header, rows)


def summarise(sweep: sweeps.Sweep, records: dict[str, dict]) -> tuple[list[str], list[dict]]:
    """Per point and decoder x condition x stimulation: counts, and mean and sample sd of each measure."""
    groups: dict[tuple, list[dict]] = {}
    for trial in sweep.trials:
        groups.setdefault((trial.point, trial.decoder, trial.condition, trial.stimulation), []).append(
            records.get(trial.id))
    numeric = lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)  # noqa: E731
    found = [k for r in records.values() for k, v in r.get("outcome", {}).items()
             if numeric(v) and k not in NOT_MEASURES]
    # the paper's three measures when the task gives them (the rest stay in the trial files), else all
    measures = [m for m in MEASURES if m in found] or list(dict.fromkeys(found))
    summary = []
    for (point, decoder, condition, stimulation), members in groups.items():
        ok = [r["outcome"] for r in members if r is not None and r["status"] == "ok"]
        row = {"point": point, "parameters": sweep.points[point], "decoder": decoder, "condition": condition,
               "stimulation": stimulation, "n_trials": len(ok),
               "n_failed": sum(r is not None and r["status"] != "ok" for r in members)}
        for measure in measures:
            values = np.array([o[measure] for o in ok if numeric(o.get(measure))], dtype=float)
            row[f"{measure}_mean"] = float(values.mean()) if len(values) else None
            row[f"{measure}_sd"] = float(values.std(ddof=1)) if len(values) > 1 else (0.0 if len(values) else None)
        summary.append(row)
    return measures, summary


def summary_csv(sweep: sweeps.Sweep, measures: list[str], summary: list[dict]) -> str:
    stats = [f"{m}_{s}" for m in measures for s in ("mean", "sd")]
    header = ["point", *sweep.keys, "decoder", "condition", "stimulation", "n_trials", "n_failed", *stats]
    rows = [[row["point"], *(label(row["parameters"].get(k, "")) for k in sweep.keys), row["decoder"],
             row["condition"], row["stimulation"], row["n_trials"], row["n_failed"],
             *("" if row[s] is None else number(row[s]) for s in stats)] for row in summary]
    return csv_text(header, rows)


def write_tables(out: Path, sweep: sweeps.Sweep, records: dict[str, dict]) -> list[dict]:
    atomic_write(out / "index.csv", index_rows(sweep, records))
    measures, summary = summarise(sweep, records)
    atomic_write(out / "summary.csv", summary_csv(sweep, measures, summary))
    return summary


def run_sweep(args) -> int:
    """The command: 0 when every trial succeeded, 1 when some failed (each listed on one line)."""
    from tqdm import tqdm

    sweep = sweeps.load(args.config)
    task = sweeps.resolve_task(sweep.task)
    out = Path(args.out)
    with sweep_folder(out, sweep, getattr(args, "force", False)) as records:
        done = {key for key, record in records.items() if record["status"] == "ok"}
        bar = None
        counts, last_index = {"ok": len(done), "failed": 0}, [time.monotonic()]

        def arrived(record):
            records[record["id"]] = record
            counts["ok" if record["status"] == "ok" else "failed"] += 1
            bar.set_postfix(completed=counts["ok"], failed=counts["failed"],
                            remaining=len(sweep.trials) - counts["ok"] - counts["failed"], refresh=False)
            bar.update(1)
            if time.monotonic() - last_index[0] > INDEX_EVERY_S:
                atomic_write(out / "index.csv", index_rows(sweep, records))
                last_index[0] = time.monotonic()

        try:
            if len(done) < len(sweep.trials):
                prepare_decoders(sweep)
                with dask_client(args.scheduler, sweep.workers, args.debug) as client:
                    check_workers(client, sweep.task)
                    bar = tqdm(total=len(sweep.trials), initial=len(done), unit="trial", desc="rhi sweep",
                               file=sys.stderr, dynamic_ncols=True, smoothing=0.05)
                    sweeps.execute(sweep, task, client, out, done, on_record=arrived)
        finally:
            if bar is not None:
                bar.close()
            summary = write_tables(out, sweep, records)
        from master.sweep_plots import plot_sweep

        plot_sweep(sweep.keys, summary, out / "figures")
    failures = [(t, records[t.id]) for t in sweep.trials if records.get(t.id, {}).get("status") == "failed"]
    for trial, record in failures[:MAX_LISTED]:
        print(f"rhi sweep: failed: point {trial.point} ({sweeps.describe(sweep.points[trial.point])}) "
              f"{trial.decoder}/{trial.condition}/{trial.stimulation} trial {trial.index} "
              f"[{trial.id}]: {record['error']}", file=sys.stderr)
        if args.debug and record.get("traceback"):
            print(record["traceback"], file=sys.stderr)
    if len(failures) > MAX_LISTED:
        print(f"rhi sweep: ... and {len(failures) - MAX_LISTED} more failures, listed in {out / 'index.csv'}",
              file=sys.stderr)
    print(f"rhi sweep: {counts['ok']} of {len(sweep.trials)} trials done ({counts['ok'] - len(done)} now), "
          f"{len(failures)} failed; results in {out}")
    if failures:
        print(f"rhi sweep: {len(failures)} trials failed; run the same command again to retry them",
              file=sys.stderr)
    return 1 if failures else 0
