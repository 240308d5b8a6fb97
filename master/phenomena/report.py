"""A phenomenon's table and figure from its sweep's trial records, with the human reference beside the model.

The x value of each trial is read from the point's full configuration, not from the swept keys, so
an edited copy of a sweep file (other points, other keys) still reports: the delay of the trial's
stimulation, the distance of its condition, the length of its trial.
"""
from __future__ import annotations

import textwrap
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from master.cosim import ConfigError  # noqa: E402
from master.outputs.figures import COLOURS, METADATA, STYLES  # noqa: E402
from master.outputs.files import atomic_write  # noqa: E402
from master.outputs.tables import csv_text, mean_sd, number  # noqa: E402
from master.phenomena import FILES, human_file  # noqa: E402
from master.sweeps import plan as sweeps  # noqa: E402
from master.sweeps.folder import read_records  # noqa: E402

HUMAN = "tab:green"
# per-trial outcome keys (master.experiment.trial_outcome) -> the table's mean (and sd) columns
OUTCOMES = {"drift_cm": True, "force_n": True, "gamma_final": False, "action_accel_mean_x_m_s2": True,
            "drift_half_time_s": True}


@dataclass(frozen=True)
class Phenomenon:
    name: str                                   # the command's name
    file: str                                   # its sweep file, beside this module
    human: str                                  # its table in human.toml
    x_name: str                                 # the table's x column
    x_label: str
    x_of: Callable[[dict, str, str], float]     # (point's configuration, condition, stimulation) -> x
    relative_to: str                            # "first", "last" or "largest": what drift_relative divides by


PHENOMENA = {p.name: p for p in (
    Phenomenon("temporal-window", FILES["temporal-window"], "temporal_window", "delay_s",
               "fixed visuo-tactile delay (s)",
               lambda config, condition, stimulation: float(config["stimulations"][stimulation]["delay_max"]), "first"),
    Phenomenon("distance", FILES["distance"], "distance", "distance_cm",
               "lateral distance between the real and the rubber hand (cm)",
               lambda config, condition, stimulation: round(100.0 * abs(config["conditions"][condition]), 9),
               "largest"),
    Phenomenon("time-course", FILES["time-course"], "time_course", "time_s",
               "time from the start of the trial (s; the first touch at 2 s)",
               lambda config, condition, stimulation: round(config["experiment"]["steps"]
                                                            * config["experiment"]["step_size"], 9), "last"),
)}


def human_references(table: str) -> list[dict]:
    with open(human_file(), "rb") as file:
        return tomllib.load(file)[table]["reference"]


def rows(phenomenon: Phenomenon, sweep: sweeps.Sweep, records: dict[str, dict]) -> list[dict]:
    """One row per x value and decoder x condition x stimulation: counts, mean (and sd) of each outcome."""
    groups: dict[tuple, list[dict]] = {}
    for trial in sweep.trials:
        record = records.get(trial.id)
        if record is None or record.get("status") != "ok":
            continue
        x = phenomenon.x_of(sweep.configs[trial.point], trial.condition, trial.stimulation)
        groups.setdefault((trial.decoder, trial.condition, trial.stimulation, x), []).append(record["outcome"])
    found = []
    for (decoder, condition, stimulation, x), outcomes in sorted(groups.items(), key=lambda item: item[0]):
        row = {"x": x, "decoder": decoder, "condition": condition, "stimulation": stimulation,
               "n_trials": len(outcomes)}
        for key in OUTCOMES:
            mean, sd = mean_sd([o.get(key, np.nan) for o in outcomes])
            row[f"{key}_mean"], row[f"{key}_sd"] = float(mean), float(sd)
        found.append(row)
    for line in lines(found).values():
        xs = [r["x"] for r in line]
        if phenomenon.relative_to == "largest":
            reference = max((r["drift_cm_mean"] for r in line), key=abs)
        else:
            reference = line[0 if phenomenon.relative_to == "first" else -1]["drift_cm_mean"]
        for r in line:
            r["drift_relative"] = r["drift_cm_mean"] / reference if reference else np.nan
        if phenomenon.name == "time-course":  # the half time is the protocol's at the longest trial only
            for r in line:
                if r["x"] != max(xs):
                    r["drift_half_time_s_mean"] = r["drift_half_time_s_sd"] = np.nan
    return found


def lines(found: list[dict]) -> dict[tuple, list[dict]]:
    """Rows grouped by decoder x condition x stimulation, each sorted by x."""
    grouped: dict[tuple, list[dict]] = {}
    for row in found:
        grouped.setdefault((row["decoder"], row["condition"], row["stimulation"]), []).append(row)
    return {key: sorted(value, key=lambda r: r["x"]) for key, value in grouped.items()}


def table(phenomenon: Phenomenon, found: list[dict]) -> str:
    stats = [f"{key}_{s}" for key, with_sd in OUTCOMES.items() for s in (("mean", "sd") if with_sd else ("mean",))]
    header = [phenomenon.x_name, "decoder", "condition", "stimulation", "n_trials", *stats, "drift_relative"]
    body = [[number(r["x"]), r["decoder"], r["condition"], r["stimulation"], r["n_trials"],
             *("" if np.isnan(r[s]) else number(r[s]) for s in stats),
             "" if np.isnan(r["drift_relative"]) else number(r["drift_relative"])] for r in found]
    return csv_text(header, body)


def draw_human(axis, references: list[dict], with_labels: bool = True) -> None:
    """Bands and marks for the human findings; never data points (they are qualitative here)."""
    tested = iter(("v", "^", "s", "D"))
    for reference in references:
        label = reference["short"] if with_labels else None
        kind = reference["kind"]
        if kind == "boundary":
            axis.axvspan(axis.get_xlim()[0], reference["value"], color=HUMAN, alpha=0.10,
                         label=f"human: effect present ({label})" if label else None)
            axis.axvline(reference["value"], color=HUMAN, ls="--", lw=1)
        elif kind == "tested":
            axis.plot(reference["values"], [0.98] * len(reference["values"]), next(tested), color=HUMAN, ms=6,
                      mfc="none",
                      transform=axis.get_xaxis_transform(), clip_on=False,
                      label=f"human: tested ({label})" if label else None)
        elif kind == "marker":
            axis.axvline(reference["value"], color="tab:purple", lw=1.5, label=f"human: {label}" if label else None)
            if "spread" in reference:
                axis.axvspan(*reference["spread"], color="tab:purple", alpha=0.25)
        elif kind == "band":
            axis.axvspan(reference["low"], reference["high"], color="tab:purple", alpha=0.10,
                         label=f"human: {label}" if label else None)
        else:
            raise ConfigError(f"human.toml: unknown kind {kind!r} ({reference['source']})")


def caption(references: list[dict], model: str) -> str:
    human = "; ".join(f"{r['short']}: {r['says']} [{r['source']}]" for r in references)
    return textwrap.fill(f"Model: {model}. Human (green/purple, qualitative, drawn as bands and marks, not "
                         f"data points): {human}.", 190)


def plot_lines(axis, phenomenon, found, value, sd=None):
    for (decoder, condition, stimulation), line in lines(found).items():
        xs = [r["x"] for r in line]
        ys = np.array([r[value] for r in line])
        if phenomenon.name == "time-course":  # no drift before the first step
            xs, ys = [0.0, *xs], np.concatenate([[0.0], ys])
        axis.plot(xs, ys, STYLES.get(decoder, ":"), marker="o", ms=3, color=COLOURS.get(condition, "k"),
                  label=f"{decoder} {condition} {stimulation}")
        if sd:
            spread = np.array([0.0] * (len(xs) - len(line)) + [r[sd] for r in line])
            axis.fill_between(xs, ys - spread, ys + spread, color=COLOURS.get(condition, "k"), alpha=0.12)
    axis.axhline(0, color="k", lw=0.8)
    axis.set_xlabel(phenomenon.x_label)
    axis.grid(alpha=0.3)


def figure(phenomenon: Phenomenon, found: list[dict], path: Path, model: str) -> None:
    references = human_references(phenomenon.human)
    panels = {"temporal-window": [("drift_relative", None, "drift / drift at the shortest delay"),
                                  ("force_n_mean", "force_n_sd", "final force (N)"),
                                  ("gamma_final_mean", None, "final gamma")],
              "distance": [("drift_cm_mean", "drift_cm_sd", "final drift (cm)"),
                           ("drift_relative", None, "drift / largest drift"),
                           ("gamma_final_mean", None, "final gamma (belief in a common cause)"),
                           ("force_n_mean", "force_n_sd", "final force (N)")],
              "time-course": [("drift_relative", None, "drift / drift at the end of the longest trial"),
                              ("drift_half_time_s_mean", None, "drift half time (s)")]}[phenomenon.name]
    fig, axes = plt.subplots(1, len(panels), figsize=(5.0 * len(panels), 4.6), squeeze=False)
    for number_, (axis, (value, sd, ylabel)) in enumerate(zip(axes[0], panels)):
        if phenomenon.name == "time-course" and value == "drift_half_time_s_mean":
            half_times(axis, found)
        else:
            plot_lines(axis, phenomenon, found, value, sd)
            axis.set_ylabel(ylabel)
        if phenomenon.name == "time-course":
            axis.set_xlim(0, max(35.0, max(r["x"] for r in found) + 2))
        draw_human(axis, references, with_labels=number_ == 0)
        if number_ == 0:
            axis.legend(fontsize=6.5, loc="best")
    fig.suptitle(f"rhi phenomenon {phenomenon.name}: model (lines) and human reference", fontsize=10)
    fig.text(0.01, 0.01, caption(references, model), fontsize=6, va="bottom", ha="left")
    fig.tight_layout(rect=(0, 0.14, 1, 0.97))
    fig.savefig(path, dpi=110, metadata=METADATA)
    plt.close(fig)


def half_times(axis, found: list[dict]) -> None:
    """The time-course protocol's result: each cell's drift half time (mean +/- sd) against the human onset."""
    cells = [r for line in lines(found).values() for r in line if not np.isnan(r["drift_half_time_s_mean"])]
    for position, r in enumerate(cells):
        axis.errorbar(r["drift_half_time_s_mean"], position, xerr=r["drift_half_time_s_sd"], fmt="o",
                      color=COLOURS.get(r["condition"], "k"), capsize=3)
    axis.set_yticks(range(len(cells)), [f"{r['decoder']} {r['condition']} {r['stimulation']}" for r in cells],
                    fontsize=7)
    axis.set_ylim(-1, len(cells))
    axis.set_xlabel("drift half time from the trial's start (model) / illusion onset (human), s")
    axis.grid(alpha=0.3)


def report(name: str, sweep_path: str | Path, out: Path) -> list[str]:
    """Write ``out/NAME.csv`` and ``out/NAME.png`` from the sweep in ``out``; returns the file names."""
    phenomenon = PHENOMENA[name]
    sweep = sweeps.load(sweep_path)
    found = rows(phenomenon, sweep, read_records(out, sweep))
    if not found:
        raise ConfigError(f"no successful trial in {out} to report {name} from")
    stem = phenomenon.file.removesuffix(".toml")
    atomic_write(out / f"{stem}.csv", table(phenomenon, found))
    config = sweep.configs[0]
    durations = sorted({c["experiment"]["steps"] * c["experiment"]["step_size"] for c in sweep.configs})
    length = (f"{durations[0]:g} s trials" if len(durations) == 1 else
              f"trials of {durations[0]:g}-{durations[-1]:g} s (each the start of the longest)")
    model = (f"{', '.join(config['experiment']['decoders'])} decoders, "
             f"{'fast (linearised)' if config['decoder']['fast'] else 'exact'} mode, {length}, "
             f"{config['experiment']['trials']} trial(s) per point, "
             f"brain.action_time_constant = {config['brain']['action_time_constant']:g} s, "
             f"brain.spatial_sd = {config['brain']['spatial_sd']:g} m")
    figure(phenomenon, found, out / f"{stem}.png", model)
    return [f"{stem}.csv", f"{stem}.png"]
