"""`rhi sweep --config FILE [--scheduler ADDRESS] [--force] --out DIR`: run a sweep, resumably.

Running the same command again runs only the trials that have no successful record (docs/sweeps.md).
"""
from __future__ import annotations

import sys
from pathlib import Path

from master.sweeps import plan as sweeps
from master.sweeps.run import run_into

MAX_LISTED = 50  # failures listed on the terminal; index.csv has all of them


def run_sweep(args) -> int:
    """The command: 0 when every trial succeeded, 1 when some failed (each listed on one line)."""
    sweep = sweeps.load(args.config, getattr(args, "model", None), getattr(args, "trials", None))
    task = sweeps.resolve_task(sweep.task)
    out = Path(args.out)
    records, now = run_into(sweep, task, out, args.scheduler, getattr(args, "force", False), args.debug)
    ok = sum(record["status"] == "ok" for record in records.values())
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
    print(f"rhi sweep: {ok} of {len(sweep.trials)} trials done ({now} now), "
          f"{len(failures)} failed; results in {out}")
    if failures:
        print(f"rhi sweep: {len(failures)} trials failed; run the same command again to retry them",
              file=sys.stderr)
    return 1 if failures else 0
