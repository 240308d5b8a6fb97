"""A sweep run into its folder: checked, locked, resumed, its chunks on a local pool or a Dask cluster, its
tables and plots written at the end (what `rhi sweep` and `rhi fit` run)."""
from __future__ import annotations

import time
from contextlib import nullcontext
from pathlib import Path

from rhi.master.outputs.files import atomic_write
from rhi.master.runtime.context import RunContext
from rhi.master.sweeps.folder import sweep_folder, written_by
from rhi.master.sweeps.plan import Sweep
from rhi.master.sweeps.plots import plot_sweep
from rhi.master.sweeps.runner import check_decoders, check_workers, dask_client, execute, prepare_decoders
from rhi.master.sweeps.tables import index_rows, write_tables

INDEX_EVERY_S = 2.0
# Between two rewrites of the index and the manifest during a run, at least this many times the last rewrite's own
# time: each rewrites every record so far, so at a fixed interval a large sweep (a fit's tens of thousands of
# trials) spent a growing share of the main process on them; this keeps that share under 1 / (1 + INDEX_SHARE).
INDEX_SHARE = 10.0


def index_due(now: float, last: float, cost: float) -> bool:
    """Whether the index and manifest are rewritten at ``now`` (s, monotonic), last rewritten at ``last``, which took
    ``cost`` seconds: after INDEX_EVERY_S, and after INDEX_SHARE times the last rewrite's own time."""
    return now - last > max(INDEX_EVERY_S, INDEX_SHARE * cost)


def run_into(sweep: Sweep, task, out: Path, context: RunContext | None = None, label: str = "rhi sweep",
             plots: bool = True, client=None) -> tuple[dict[str, dict], int]:
    """Run every trial of ``sweep`` that ``out`` holds no successful record of; returns (every record by trial
    id, how many ran now). context: force (replace a different sweep in ``out``), scheduler, debug. client: a
    callable giving a dask Client to run on, checked and kept open by the caller (several sweeps on one pool);
    default: one of its own, on ``context.scheduler`` or a local pool.

    A stop (Ctrl-C, a kill) leaves the records written so far, each whole: the same call again runs only
    the rest (docs/sweeps.md)."""
    from rhi.master.runtime.progress import bar as progress_bar

    context = context or RunContext()
    check_decoders(sweep)
    with sweep_folder(out, sweep, context.force) as (records, manifest):
        done = {key for key, record in records.items() if record["status"] == "ok"}
        bar = None
        counts, last_index, index_cost = {"ok": len(done), "failed": 0}, [time.monotonic()], [0.0]

        def arrived(record):
            records[record["id"]] = record
            manifest.add(f"trials/{record['id']}.json")
            counts["ok" if record["status"] == "ok" else "failed"] += 1
            bar.set_postfix(completed=counts["ok"], failed=counts["failed"],
                            remaining=len(sweep.trials) - counts["ok"] - counts["failed"], refresh=False)
            bar.update(1)
            began = time.monotonic()
            if index_due(began, last_index[0], index_cost[0]):
                atomic_write(out / "index.csv", index_rows(sweep, records))
                manifest.add("index.csv")
                manifest.save()  # the files written so far, listed as the index is
                last_index[0] = time.monotonic()
                index_cost[0] = last_index[0] - began

        try:
            if len(done) < len(sweep.trials):
                prepare_decoders(sweep)
                pool_context = (nullcontext(client()) if client else
                                dask_client(context.scheduler, sweep.workers, context.debug))
                with pool_context as pool:
                    if not client:
                        check_workers(pool, sweep.task)
                    bar = progress_bar(total=len(sweep.trials), initial=len(done), unit="trial", desc=label,
                                       dynamic_ncols=True, smoothing=0.05)
                    execute(sweep, task, pool, out, done, on_record=arrived)
        finally:
            if bar is not None:
                bar.close()
            summary = write_tables(out, sweep, records)
            for name in ("index.csv", "summary.csv"):
                manifest.add(name)
            manifest.save()
        if plots:
            plot_sweep(sweep.keys, summary, out / "figures")
            for name in written_by(sweep):
                if name.startswith("figures/"):
                    manifest.add(name)
            manifest.save()
    return records, counts["ok"] - len(done)
