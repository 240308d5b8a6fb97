"""The experiment's files (DESIGN.md, "Command line contract"): summary.csv, trials.csv, run.json, figures/.

A run writes into a staging folder beside DIR and renames it to DIR at the end,
so DIR holds either a complete run or nothing from this one.
"""
from __future__ import annotations

import csv
import io
import numpy as np


SUMMARY_COLUMNS = ["decoder", "condition", "stimulation", "n_trials", "drift_cm_mean", "drift_cm_sd",
                   "force_n_mean", "force_n_sd", "gamma_final_mean"]
TRIAL_KEYS = ["decoder", "condition", "stimulation", "trial", "seed"]


def csv_text(header: list[str], rows) -> str:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    return buffer.getvalue()


def number(value: float) -> str:
    """Fixed formatting, so that the same numbers always give the same bytes."""
    return f"{value:.6g}"


def summary(trials, final: dict[str, np.ndarray]) -> list[list]:
    """One row per decoder x condition x stimulation, from end-of-trial values (``final[key][trial]``)."""
    groups: dict[tuple, list[int]] = {}
    for position, trial in enumerate(trials):
        groups.setdefault((trial.decoder, trial.condition, trial.stimulation), []).append(position)
    rows = []
    for (decoder, condition, stimulation), members in groups.items():
        drift, force, gamma = (final[key][members] for key in ("drift_cm", "force_x_n", "gamma"))
        sd = lambda x: float(np.std(x, ddof=1)) if len(x) > 1 else 0.0  # noqa: E731
        rows.append([decoder, condition, stimulation, len(members), number(drift.mean()), number(sd(drift)),
                     number(force.mean()), number(sd(force)), number(gamma.mean())])
    return rows


def trials_csv(trials, times: np.ndarray, per_step: dict[str, np.ndarray]) -> str:
    """Tidy: one row per trial x step; ``per_step[key]`` has shape (steps + 1, B)."""
    keys = list(per_step)
    table = np.stack([per_step[key] for key in keys], axis=-1)  # steps+1, B, K
    rows = []
    for position, trial in enumerate(trials):
        identity = [trial.decoder, trial.condition, trial.stimulation, trial.index, trial.seed]
        for step, time in enumerate(times):
            rows.append(identity + [step, number(time)] + [number(x) for x in table[step, position]])
    return csv_text(TRIAL_KEYS + ["step", "time_s"] + keys, rows)
