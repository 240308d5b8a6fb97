"""The experiment's tables (docs/design.md, "Command line contract"): summary.csv and trials.csv, and the
statistics every table and figure shares: trials grouped by cell, mean and sample sd (ddof 1)."""
from __future__ import annotations

import csv
import io

import numpy as np

# The output schema's version, in run.json: raised whenever a column of summary.csv or trials.csv, or a
# key of run.json, is renamed or removed (2: the action measure's columns named as in trials.csv).
SCHEMA_VERSION = 2
SUMMARY_COLUMNS = ["decoder", "condition", "stimulation", "n_trials", "drift_cm_mean", "drift_cm_sd",
                   "force_n_mean", "force_n_sd", "gamma_final_mean",
                   "action_accel_mean_x_m_s2_mean", "action_accel_mean_x_m_s2_sd",
                   "action_accel_x_m_s2_mean", "action_accel_x_m_s2_sd"]
# The per-trial values (keys of ``final`` in :func:`summary`) behind the mean +/- sd column pairs, in order.
SUMMARY_MEASURES = ("drift_cm", "force_x_n", "gamma", "action_accel_mean_x_m_s2", "action_accel_x_m_s2")
TRIAL_KEYS = ["decoder", "condition", "stimulation", "trial", "seed"]


def probe_name(time_s: float) -> str:
    """The measure of the drift read at ``time_s`` (s): ``drift_at_60s_cm``, ``drift_at_0.5s_cm``."""
    return f"drift_at_{float(time_s):.10g}s_cm"


def probe_measures(probe_times) -> list[str]:
    """The per-trial values of the drift read at ``probe_times`` (s): ``drift_at_60s_cm``, ... in order."""
    return [probe_name(time) for time in probe_times]


def summary_columns(probe_times=()) -> list[str]:
    """summary.csv's columns: :data:`SUMMARY_COLUMNS`, then a mean and sd of the drift at each probe time (s,
    ``experiment.probe_times``): ``drift_at_60s_cm_mean``, ``drift_at_60s_cm_sd``, ..."""
    return SUMMARY_COLUMNS + [f"{name}_{stat}" for name in probe_measures(probe_times) for stat in ("mean", "sd")]


def csv_text(header: list[str], rows) -> str:
    """``header`` and ``rows`` as CSV text, one line each, every line ending in a newline; every cell through
    :func:`safe_cell` (the one CSV writer of rhi: no free text of the user's becomes a spreadsheet formula)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(map(safe_cell, header))
    writer.writerows(map(safe_cell, row) for row in rows)
    return buffer.getvalue()


FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")  # what a spreadsheet takes for the start of a formula (OWASP)


def safe_cell(value):
    """``value`` as a CSV cell a spreadsheet will not run: text starting with = + - @, a tab or a carriage return
    gets a leading apostrophe (OWASP, "CSV Injection"), unless it reads as a number (``-1.5``, ``-inf``: rhi's
    own numbers stay numbers); anything else is left as it is."""
    if isinstance(value, str) and value[:1] in FORMULA_STARTS:
        try:
            float(value)
        except ValueError:
            return "'" + value
    return value


NUMBER = "%.6g"  # every number in a table: fixed formatting, so that the same numbers always give the same bytes


def number(value: float) -> str:
    """``value`` as every table writes a number: ``NUMBER``, ``%.6g``."""
    return NUMBER % value


def cells(items, key=lambda item: (item.decoder, item.condition, item.stimulation)) -> dict[tuple, list[int]]:
    """Positions of ``items`` grouped by ``key`` (by default the cell: decoder, condition, stimulation),
    in first-seen order."""
    groups: dict[tuple, list[int]] = {}
    for position, item in enumerate(items):
        groups.setdefault(key(item), []).append(position)
    return groups


def mean_sd(values, axis: int = 0):
    """Mean and sample standard deviation (ddof 1; 0 for a single value) along ``axis``; (None, None) if empty."""
    values = np.asarray(values, dtype=float)
    count = values.shape[axis]
    if count == 0:
        return None, None
    sd = values.std(axis=axis, ddof=1) if count > 1 else np.zeros_like(values.mean(axis=axis))
    return values.mean(axis=axis), sd


def summary(trials, final: dict[str, np.ndarray], planned=None, probe_times=()) -> list[list]:
    """One row per decoder x condition x stimulation, from per-trial values (``final[key][trial]``).

    ``final`` holds the end-of-trial values and the trial means of rhi.master.tasks.illusion.measures.end_of_trial:
    drift, force, gamma (mean only), then the action measure J a_dot (m/s^2): its mean over the
    trial and its final value, each as mean and sample sd over the cell's trials.
    planned: every cell the protocol planned, in order (default: those of ``trials``); a planned cell with no
    trial left (every one failed) has a row with n_trials 0 and empty statistics.
    probe_times: ``experiment.probe_times`` (s): the drift at each, mean and sd, after those (:func:`summary_columns`).
    """
    found = cells(trials)
    rows = []
    probed = probe_measures(probe_times)
    for cell in (planned if planned is not None else found):
        members = found.get(cell, [])
        if not members:
            rows.append([*cell, 0] + [""] * (len(summary_columns(probe_times)) - 4))
            continue
        stats = [mean_sd(final[key][members]) for key in SUMMARY_MEASURES]
        (drift, drift_sd), (force, force_sd), (gamma, _), (accel_mean, accel_mean_sd), (accel, accel_sd) = stats
        rows.append([*cell, len(members), number(drift), number(drift_sd),
                     number(force), number(force_sd), number(gamma), number(accel_mean), number(accel_mean_sd),
                     number(accel), number(accel_sd)]
                    + [number(value) for key in probed for value in mean_sd(final[key][members])])
    return rows


def trials_csv(trials, times: np.ndarray, per_step: dict[str, np.ndarray]) -> str:
    """Tidy: one row per trial x step; ``per_step[key]`` has shape (steps + 1, B)."""
    keys = list(per_step)
    table = np.stack([per_step[key] for key in keys], axis=-1)  # steps+1, B, K
    numbers = ",".join([NUMBER] * (len(keys) + 1))  # a row's time and measures, formatted in one go
    lines = [csv_text(TRIAL_KEYS + ["step", "time_s"] + keys, [])]
    for position, trial in enumerate(trials):
        identity = f"{trial.decoder},{trial.condition},{trial.stimulation},{trial.index},{trial.seed},"
        values = np.column_stack([times, table[:, position]]).tolist()
        lines += [f"{identity}{step}," + numbers % tuple(row) + "\n" for step, row in enumerate(values)]
    return "".join(lines)
