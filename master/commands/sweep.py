"""`rhi sweep --config FILE [--scheduler ADDRESS] [--force] --out DIR`: run a sweep, resumably.

Running the same command again runs only the trials that have no successful record (docs/sweeps.md).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

from master.outputs.files import atomic_write
from master.sweeps import plan as sweeps
from master.sweeps.folder import sweep_folder
from master.sweeps.plots import plot_sweep
from master.sweeps.runner import check_decoders, check_workers, dask_client, execute, prepare_decoders
from master.sweeps.tables import index_rows, write_tables

INDEX_EVERY_S = 2.0
MAX_LISTED = 50  # failures listed on the terminal; index.csv has all of them


def run_sweep(args) -> int:
    """The command: 0 when every trial succeeded, 1 when some failed (each listed on one line)."""
    from tqdm import tqdm

    sweep = sweeps.load(args.config, getattr(args, "model", None), getattr(args, "trials", None))
    task = sweeps.resolve_task(sweep.task)
    out = Path(args.out)
    check_decoders(sweep)
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
                    execute(sweep, task, client, out, done, on_record=arrived)
        finally:
            if bar is not None:
                bar.close()
            summary = write_tables(out, sweep, records)
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
