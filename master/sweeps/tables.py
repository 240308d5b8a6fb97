"""A sweep's tables: index.csv (one row per finished trial) and summary.csv (per point and cell)."""
from __future__ import annotations

import json
from pathlib import Path

from rhi.master.outputs.files import atomic_write
from rhi.master.outputs.tables import cells, csv_text, mean_sd, number
from rhi.master.sweeps.plan import Sweep

MEASURES = ("drift_cm", "force_n", "gamma_final")  # what summary.csv and the figures show
NOT_MEASURES = ("seed",)  # numbers in an outcome that identify the trial rather than measure it


def label(value) -> str:
    """A swept value as a table cell: a string as it is, anything else as JSON."""
    return value if isinstance(value, str) else json.dumps(value)


def index_rows(sweep: Sweep, records: dict[str, dict]) -> str:
    """index.csv's text: a row per trial with a record (its point's values, status, measures, time and error)."""
    header = ["id", "point", *sweep.keys, "decoder", "condition", "stimulation", "trial", "seed", "status",
              *MEASURES, "elapsed_s", "error"]
    rows, labels = [], {}  # each point's values as cells, made once per point rather than once per trial
    for trial in sweep.trials:
        record = records.get(trial.id)
        if record is None:
            continue
        outcome = record.get("outcome", {})
        if trial.point not in labels:
            labels[trial.point] = [label(sweep.points[trial.point].get(k, "")) for k in sweep.keys]
        rows.append([trial.id, trial.point, *labels[trial.point],
                     trial.decoder, trial.condition, trial.stimulation, trial.index, trial.seed,
                     record["status"], *(repr(outcome[m]) if m in outcome else "" for m in MEASURES),
                     record.get("elapsed_s", ""), record.get("error", "")])
    return csv_text(header, rows)


def summarise(sweep: Sweep, records: dict[str, dict]) -> tuple[list[str], list[dict]]:
    """Per point and decoder x condition x stimulation: counts, and mean and sample sd of each measure."""
    groups = cells(sweep.trials, key=lambda t: (t.point, t.decoder, t.condition, t.stimulation))
    numeric = lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)  # noqa: E731
    found = [k for r in records.values() for k, v in r.get("outcome", {}).items()
             if numeric(v) and k not in NOT_MEASURES]
    # the paper's three measures when the task gives them (the rest stay in the trial files), else all
    measures = [m for m in MEASURES if m in found] or list(dict.fromkeys(found))
    summary = []
    for (point, decoder, condition, stimulation), positions in groups.items():
        members = [records.get(sweep.trials[position].id) for position in positions]
        ok = [r["outcome"] for r in members if r is not None and r["status"] == "ok"]
        row = {"point": point, "parameters": sweep.points[point], "decoder": decoder, "condition": condition,
               "stimulation": stimulation, "n_trials": len(ok),
               "n_failed": sum(r is not None and r["status"] != "ok" for r in members)}
        for measure in measures:
            mean, sd = mean_sd([o[measure] for o in ok if numeric(o.get(measure))])
            row[f"{measure}_mean"], row[f"{measure}_sd"] = (None, None) if mean is None else (float(mean), float(sd))
        summary.append(row)
    return measures, summary


def summary_csv(sweep: Sweep, measures: list[str], summary: list[dict]) -> str:
    """summary.csv's text: a row per point and cell of ``summary`` (:func:`summarise`), mean and sd of ``measures``."""
    stats = [f"{m}_{s}" for m in measures for s in ("mean", "sd")]
    header = ["point", *sweep.keys, "decoder", "condition", "stimulation", "n_trials", "n_failed", *stats]
    rows = [[row["point"], *(label(row["parameters"].get(k, "")) for k in sweep.keys), row["decoder"],
             row["condition"], row["stimulation"], row["n_trials"], row["n_failed"],
             *("" if row[s] is None else number(row[s]) for s in stats)] for row in summary]
    return csv_text(header, rows)


def write_tables(out: Path, sweep: Sweep, records: dict[str, dict]) -> list[dict]:
    """Write index.csv and summary.csv into ``out``; returns the summary's rows (:func:`summarise`)."""
    atomic_write(out / "index.csv", index_rows(sweep, records))
    measures, summary = summarise(sweep, records)
    atomic_write(out / "summary.csv", summary_csv(sweep, measures, summary))
    return summary
