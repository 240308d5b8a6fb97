"""`rhi sweep --config FILE [--scheduler ADDRESS] [--force] --out DIR`: run a sweep, resumably.

Running the same command again runs only the trials that have no successful record (docs/sweeps.md).
"""
from __future__ import annotations

import logging
from pathlib import Path

MAX_LISTED = 50  # failures listed on the terminal; index.csv has all of them
HELP = "run a parameter sweep, locally or on a Dask cluster"
log = logging.getLogger("rhi.sweep")


def add_arguments(parser) -> None:
    """`rhi sweep`'s arguments."""
    parser.add_argument("--config", metavar="FILE", required=True, help="the sweep file (TOML, see docs/sweeps.md)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="a Dask scheduler, tcp://HOST:PORT (default: a process pool on this machine)")
    parser.add_argument("--out", metavar="DIR", required=True)
    parser.add_argument("--force", action="store_true", help="replace a different sweep in DIR")
    parser.add_argument("--model", metavar="NAME",
                        help="the model, instead of the sweep file's sweep.model (default there: paper; a name or "
                             "FILE.py:Class, docs/model.md)")


def run(args) -> int:
    """The command: 0 when every trial succeeded, 1 when some failed (each listed on one line)."""
    from rhi.master.runtime.context import RunContext

    return sweep_and_report(args.config, args.out, RunContext.of(args), getattr(args, "model", None))


def sweep_and_report(path, out, context, model: str | None = None, trials: int | None = None) -> int:
    """Run the sweep file ``path`` into ``out`` (resumably) and print what was done; 0 when every trial succeeded,
    1 when some failed. context: a :class:`~rhi.master.runtime.context.RunContext` (force, scheduler, debug). model,
    trials: instead of the file's ``sweep.model`` and ``sweep.trials``."""
    from rhi.master.sweeps import plan as sweeps
    from rhi.master.sweeps.run import run_into

    sweep = sweeps.load(path, model, trials)
    task = sweeps.resolve_task(sweep.task)
    out = Path(out)
    records, now = run_into(sweep, task, out, context)
    ok = sum(record["status"] == "ok" for record in records.values())
    failures = [(t, records[t.id]) for t in sweep.trials if records.get(t.id, {}).get("status") == "failed"]
    for trial, record in failures[:MAX_LISTED]:
        log.error(f"rhi sweep: failed: point {trial.point} ({sweeps.describe(sweep.points[trial.point])}) "
                  f"{trial.decoder}/{trial.condition}/{trial.stimulation} trial {trial.index} "
                  f"[{trial.id}]: {record['error']}")
        if context.debug and record.get("traceback"):
            log.error(record["traceback"].rstrip("\n"))
    if len(failures) > MAX_LISTED:
        log.error(f"rhi sweep: ... and {len(failures) - MAX_LISTED} more failures, listed in {out / 'index.csv'}")
    print(f"rhi sweep: {ok} of {len(sweep.trials)} trials done ({now} now), "
          f"{len(failures)} failed; results in {out}")
    if failures:
        log.error(f"rhi sweep: {len(failures)} trials failed; run the same command again to retry them")
    return 1 if failures else 0
