"""A cohort's outputs, written when a population varies (docs/population.md): the between-participant statistics
of each measure per cell (columns appended to summary.csv), each participant's drawn parameters
(participants.csv), and the participants of every cell as a strip plot (figures/cohort.png)."""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from rhi.master.outputs.files import atomic_write
from rhi.master.outputs.tables import cells, csv_text, number

QUANTILES = (0.1, 0.5, 0.9)  # q10, q50, q90: numpy's default (linear) quantile, Hyndman & Fan (1996) type 7
# The per-trial values (keys of end_of_trial's ``final``) a cohort reports, with summary.csv's name for each.
MEASURES = {"drift_cm": "drift_cm", "force_x_n": "force_n", "gamma": "gamma_final",
            "action_accel_mean_x_m_s2": "action_accel_mean_x_m_s2", "action_accel_x_m_s2": "action_accel_x_m_s2"}
STRIPS = ("drift_cm", "force_x_n")  # the figure's measures, with the model's own (an onset, say)
METADATA = {"Software": None}  # no version string in the file: same data, same bytes


def statistics(values: np.ndarray, wanted: list[str]) -> list[float]:
    """Between-participant statistics of one cell's values, each of ``wanted`` ("mean", "sd": the sample sd with
    ddof 1, 0 for one value; "q10", ...: :data:`QUANTILES`), over the participants whose value is defined (NaN: an
    onset never reached); NaN for all when none is."""
    values = np.asarray(values, dtype=float)
    values = values[~np.isnan(values)]
    if values.size == 0:
        return [np.nan] * len(wanted)
    quantiles = dict(zip(STATISTICS[2:], np.quantile(values, QUANTILES).tolist()))
    known = {"mean": float(values.mean()), "sd": float(values.std(ddof=1)) if values.size > 1 else 0.0, **quantiles}
    return [known[statistic] for statistic in wanted]


STATISTICS = ("mean", "sd", *(f"q{round(100 * q)}" for q in QUANTILES))


def wanted(name: str, present) -> list[str]:
    """The statistics of measure ``name`` a cohort adds: its quantiles, and its mean and sd where summary.csv's
    columns (``present``) lack them."""
    return [statistic for statistic in STATISTICS if f"{name}_{statistic}" not in present]


def columns(measures: dict[str, str], present) -> list[str]:
    """The columns appended to summary.csv (whose columns are ``present``) for ``measures`` (final's key -> its
    name): ``drift_cm_q10``, ..., ``gamma_final_sd``, ``ownership_onset_s_mean``, ..."""
    return [f"{name}_{statistic}" for name in measures.values() for statistic in wanted(name, present)]


def measures_of(own: tuple = (), probes: tuple = ()) -> dict[str, str]:
    """The measures a cohort reports: :data:`MEASURES`, the drift at each probe time, the model's own measures
    (``own``: Model.measures' columns), each under its own name."""
    return {**MEASURES, **{name: name for name in (*probes, *own)}}


def summary_cells(trials, final: dict, planned, measures: dict[str, str], present) -> list[list[str]]:
    """Per planned cell, in order: the cells of :func:`columns` (empty where the cell has no trial left)."""
    found = cells(trials)
    rows = []
    for cell in planned:
        members = found.get(cell, [])
        if not members:
            rows.append([""] * len(columns(measures, present)))
            continue
        rows.append([number(value) for key, name in measures.items()
                     for value in statistics(final[key][members], wanted(name, present))])
    return rows


def participants_csv(indices, seeds, drawn: dict[str, np.ndarray]) -> str:
    """participants.csv: one row per participant, its index (the trial index in every cell), its seed, and the
    value of each population key (the configuration key's unit)."""
    keys = list(drawn)
    return csv_text(["participant", "participant_seed", *keys],
                    [[index, seed, *(number(drawn[key][row]) for key in keys)]
                     for row, (index, seed) in enumerate(zip(indices, seeds))])


def strip_figure(trials, final: dict, measures) -> Figure:
    """Per measure an axis, per cell a column of dots, one per participant (spread sideways evenly in index order, no
    random jitter: same data, same picture), and a bar at the cell's median."""
    found = cells(trials)
    labels = ["\n".join(cell) for cell in found]
    figure = Figure(figsize=(max(4.0, 0.9 * len(found) + 1.5), 2.8 * len(measures)))
    axes = figure.subplots(len(measures), 1, squeeze=False)[:, 0]
    for axis, key in zip(axes, measures):
        for position, members in enumerate(found.values()):
            values = np.asarray(final[key][members], dtype=float)
            offsets = np.linspace(-0.25, 0.25, len(values)) if len(values) > 1 else np.zeros(1)
            axis.plot(position + offsets, values, "o", ms=3, alpha=0.7, color="tab:blue", gid="participants")
            if np.isfinite(values).any():
                axis.plot([position - 0.3, position + 0.3], [np.nanmedian(values)] * 2, color="k", lw=1.5,
                          gid="median")
        axis.axhline(0, color="0.6", lw=0.6)
        axis.set_ylabel(key)
        axis.set_xticks(range(len(labels)), labels, fontsize=7)
    axes[0].set_title("participants per cell (dots) and their median (bar)")
    figure.tight_layout()
    return figure


def write_strip_figure(path, trials, final: dict, measures) -> None:
    """figures/cohort.png (a job of the experiment's writing), whole or not at all."""
    figure = strip_figure(trials, final, measures)
    atomic_write(path, lambda file: figure.savefig(file, format="png", dpi=110, metadata=METADATA))
