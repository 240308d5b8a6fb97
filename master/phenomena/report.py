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
from typing import TYPE_CHECKING, Callable

import numpy as np

from rhi.master.cosim import ConfigError
from rhi.master.outputs.figures import COLOURS, STYLES, save, subplots
from rhi.master.outputs.files import atomic_write
from rhi.master.outputs.tables import csv_text, mean_sd, number
from rhi.master import models as registry
from rhi.master.phenomena import FILES, human_file
from rhi.master.sweeps import plan as sweeps
from rhi.master.sweeps.folder import read_records

if TYPE_CHECKING:
    from matplotlib.figure import Figure  # matplotlib loads where a figure is drawn, not with the module

HUMAN = "tab:green"
# per-trial outcome keys (rhi.master.tasks.illusion.trial_outcome) -> the table's mean (and sd) columns
OUTCOMES = {"drift_cm": True, "force_n": True, "gamma_final": False, "action_accel_mean_x_m_s2": True,
            "drift_half_time_s": True, "drift_half_decay_s": True}
POPULATION = ("drift_cm", "drift_half_time_s", "drift_half_decay_s")  # also as median, 25th and 75th percentile
STIMULATION_CODES = {"sync": 0.0, "async": 1.0, "vision": 2.0}  # the vision-only protocol's x
STIMULATION_COLOURS = {"sync": "tab:red", "async": "tab:blue", "vision": "tab:green"}


@dataclass(frozen=True)
class Phenomenon:
    """A phenomenon run as a sweep: its files, and how its table's x is read from a trial.

    Attributes
    ----------
    name : str
        The command's name, e.g. ``temporal-window``.
    file : str
        Its sweep file, beside this module.
    human : str
        Its table in human.toml.
    x_name : str
        The table's x column, e.g. ``delay_s``.
    x_label : str
        The figures' x axis label.
    x_of : callable
        (point's configuration, condition, stimulation) -> x, in the x column's unit.
    relative_to : str
        ``first``, ``last`` or ``largest``: the drift that ``drift_relative`` divides by, along each line.
    """

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
    Phenomenon("persistence", FILES["persistence"], "persistence", "time_s",
               "time from the start of the trial (s; the last touch at 30 s)",
               lambda config, condition, stimulation: round(config["experiment"]["steps"]
                                                            * config["experiment"]["step_size"], 9), "first"),
    Phenomenon("vision-only", FILES["vision-only"], "vision_only", "stimulation_code",
               "stimulation: 0 synchronous, 1 asynchronous, 2 vision only (no touch)",
               lambda config, condition, stimulation: STIMULATION_CODES.get(stimulation, 3.0), "first"),
    Phenomenon("blocks", FILES["blocks"], "blocks", "block_s",
               "length of each stroking block (s; 5 s pauses between blocks, the drift read at 120 s)",
               lambda config, condition, stimulation: block_length(config, stimulation), "largest"),
)}


def block_length(config: dict, stimulation: str) -> float:
    """s: the first stroking block's length of ``stimulation``, or the trial's length where it has one block."""
    blocks = config["stimulations"][stimulation]["blocks"]
    if blocks:
        return round(float(blocks[0][1] - blocks[0][0]), 9)
    return round(config["experiment"]["steps"] * config["experiment"]["step_size"], 9)


def human_references(table: str) -> list[dict]:
    """The human references of ``table`` in human.toml (its ``reference`` list)."""
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
               "line": "all" if phenomenon.name == "vision-only" else stimulation, "n_trials": len(outcomes)}
        for key in OUTCOMES:
            mean, sd = mean_sd([o.get(key, np.nan) for o in outcomes])
            row[f"{key}_mean"], row[f"{key}_sd"] = float(mean), float(sd)
        for key in POPULATION:
            values = np.array([o.get(key, np.nan) for o in outcomes], dtype=float)
            quartiles = np.nanpercentile(values, (25, 50, 75)) if np.isfinite(values).any() else [np.nan] * 3
            row[f"{key}_q25"], row[f"{key}_median"], row[f"{key}_q75"] = map(float, quartiles)
        found.append(row)
    for line in lines(found).values():
        xs = [r["x"] for r in line]
        if phenomenon.relative_to == "largest":
            reference = max((r["drift_cm_mean"] for r in line), key=abs)
        else:
            reference = line[0 if phenomenon.relative_to == "first" else -1]["drift_cm_mean"]
        for r in line:
            r["drift_relative"] = r["drift_cm_mean"] / reference if reference else np.nan
        if phenomenon.name in ("time-course", "persistence"):  # the protocol's half times: the longest trial's
            for r in line:
                if r["x"] != max(xs):
                    for key in ("drift_half_time_s", "drift_half_decay_s"):
                        for stat in ("mean", "sd", "q25", "median", "q75"):
                            r[f"{key}_{stat}"] = np.nan
    return found


def lines(found: list[dict]) -> dict[tuple, list[dict]]:
    """Rows grouped by decoder x condition x stimulation (the vision-only protocol: decoder x condition, its x
    being the stimulation), each sorted by x."""
    grouped: dict[tuple, list[dict]] = {}
    for row in found:
        grouped.setdefault((row.get("model", "paper"), row["decoder"], row["condition"], row["line"]), []).append(row)
    return {key: sorted(value, key=lambda r: r["x"]) for key, value in grouped.items()}


def table(phenomenon: Phenomenon, found: list[dict]) -> str:
    """NAME.csv's text: a row per row of ``found`` (:func:`rows`), the outcomes' statistics and ``drift_relative``;
    a NaN is an empty cell."""
    stats = [f"{key}_{s}" for key, with_sd in OUTCOMES.items() for s in (("mean", "sd") if with_sd else ("mean",))]
    stats += [f"{key}_{s}" for key in POPULATION for s in ("median", "q25", "q75")]
    header = ["model", phenomenon.x_name, "decoder", "condition", "stimulation", "n_trials", *stats, "drift_relative"]
    body = [[r.get("model", "paper"), number(r["x"]), r["decoder"], r["condition"], r["stimulation"], r["n_trials"],
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
    """The figure's caption: the model, and what the human references found, wrapped at 190 characters."""
    human = "; ".join(f"{r['short']}: {r['says']} [{r['source']}]" for r in references)
    return textwrap.fill(f"Model: {model}. Human (green/purple, qualitative, drawn as bands and marks, not "
                         f"data points): {human}.", 190)


def plot_lines(axis, phenomenon, found, value, sd=None):
    """Draw the column ``value`` against x on ``axis``, a line per decoder x condition x stimulation, and the
    column ``sd`` as a band around it when given."""
    for (_, decoder, condition, stimulation), line in lines(found).items():
        # a condition of its own (not left/center/right): coloured by the stimulation
        colour = COLOURS.get(condition, STIMULATION_COLOURS.get(stimulation, "k"))
        xs = [r["x"] for r in line]
        ys = np.array([r[value] for r in line])
        if phenomenon.name in ("time-course",):  # no drift before the first step
            xs, ys = [0.0, *xs], np.concatenate([[0.0], ys])
        axis.plot(xs, ys, STYLES.get(decoder, ":"), marker="o", ms=3, color=colour,
                  label=f"{decoder} {condition} {stimulation}")
        if sd:
            spread = np.array([0.0] * (len(xs) - len(line)) + [r[sd] for r in line])
            axis.fill_between(xs, ys - spread, ys + spread, color=colour, alpha=0.12)
    axis.axhline(0, color="k", lw=0.8)
    axis.set_xlabel(phenomenon.x_label)
    axis.grid(alpha=0.3)


PANELS = {"temporal-window": [("drift_relative", None, "drift / drift at the shortest delay"),
                              ("force_n_mean", "force_n_sd", "final force (N)"),
                              ("gamma_final_mean", None, "final gamma")],
          "distance": [("drift_cm_mean", "drift_cm_sd", "final drift (cm)"),
                       ("drift_relative", None, "drift / largest drift"),
                       ("gamma_final_mean", None, "final gamma (belief in a common cause)"),
                       ("force_n_mean", "force_n_sd", "final force (N)")],
          "time-course": [("drift_relative", None, "drift / drift at the end of the longest trial"),
                          ("drift_half_time_s_mean", None, "drift half time (s)")],
          "persistence": [("drift_cm_mean", "drift_cm_sd", "drift (cm)"),
                          ("drift_relative", None, "drift / drift at the last touch (30 s)"),
                          ("gamma_final_mean", None, "gamma (belief in a common cause)")],
          "vision-only": [("drift_cm_mean", "drift_cm_sd", "final drift (cm)"),
                          ("drift_relative", None, "drift / synchronous drift"),
                          ("gamma_final_mean", None, "final gamma")],
          "blocks": [("drift_cm_mean", "drift_cm_sd", "drift at 120 s (cm)"),
                     ("gamma_final_mean", None, "gamma at 120 s")]}


def figure(phenomenon: Phenomenon, found: list[dict], descriptions: dict[str, str]) -> Figure:
    """One row of panels per model (paper above causal), each with the human reference."""
    references = human_references(phenomenon.human)
    panels = PANELS[phenomenon.name]
    models = list(dict.fromkeys(r.get("model", "paper") for r in found))  # in the order they ran
    fig, axes = subplots(len(models), len(panels), figsize=(5.0 * len(panels), 4.2 * len(models) + 0.8),
                             squeeze=False)
    for row_axes, model in zip(axes, models):
        mine = [r for r in found if r.get("model", "paper") == model]
        for number_, (axis, (value, sd, ylabel)) in enumerate(zip(row_axes, panels)):
            if value == "drift_half_time_s_mean":
                half_times(axis, mine)
            else:
                plot_lines(axis, phenomenon, mine, value, sd)
                axis.set_ylabel(ylabel)
            if phenomenon.name == "time-course":
                axis.set_xlim(0, max(35.0, max(r["x"] for r in found) + 2))
            draw_human(axis, references, with_labels=number_ == 0)
            axis.set_title(f"model {model}", fontsize=9)
            if number_ == 0:
                axis.legend(fontsize=6.5, loc="best")
    fig.suptitle(f"rhi phenomenon {phenomenon.name}: the models (lines) and the human reference", fontsize=10)
    text = " | ".join(f"{model}: {descriptions[model]}" for model in models)
    fig.text(0.01, 0.005, caption(references, text), fontsize=6, va="bottom", ha="left")
    fig.tight_layout(rect=(0, 0.1 / len(models) + 0.04, 1, 0.97))
    return fig


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


def describe(config: dict, sweep: sweeps.Sweep) -> str:
    """The model's run in words, for the caption."""
    durations = sorted({c["experiment"]["steps"] * c["experiment"]["step_size"] for c in sweep.configs})
    length = (f"{durations[0]:g} s trials" if len(durations) == 1 else
              f"trials of {durations[0]:g}-{durations[-1]:g} s (each the start of the longest)")
    text = (f"{', '.join(config['experiment']['decoders'])} decoders, "
            f"{'fast (linearised)' if config['decoder']['fast'] else 'exact'} mode, {length}, "
            f"{config['experiment']['trials']} trial(s) per point")
    if registry.of(config).trials_per_point(config):
        return text + " (one simulated participant each)"
    return text + (f", brain.action_time_constant = {config['brain']['action_time_constant']:g} s, "
                   f"brain.spatial_sd = {config['brain']['spatial_sd']:g} m")


def report(name: str, sweep_path: str | Path, out: Path, models: dict[str, Path] | None = None,
           trials: dict[str, int] | None = None) -> list[str]:
    """Write ``out/NAME.csv`` and ``out/NAME.png`` from the sweeps of each model; returns the file names.

    models: model -> the folder its sweep ran in (default: ``{"paper": out}``, the sweep in ``out``);
    trials: model -> the trials per point it ran with (as ``rhi phenomenon`` gave them).
    """
    phenomenon = PHENOMENA[name]
    found, descriptions = [], {}
    for model, folder in (models or {"paper": out}).items():
        sweep = sweeps.load(sweep_path, model=model, trials=(trials or {}).get(model))
        mine = rows(phenomenon, sweep, read_records(folder, sweep))
        label = registry.get(model).name
        found += [{**r, "model": label} for r in mine]
        descriptions[label] = describe(sweep.configs[0], sweep)
    if not found:
        raise ConfigError(f"no successful trial in {out} to report {name} from")
    stem = phenomenon.file.removesuffix(".toml")
    atomic_write(out / f"{stem}.csv", table(phenomenon, found))
    save(figure(phenomenon, found, descriptions), out / f"{stem}.png")
    return [f"{stem}.csv", f"{stem}.png"]
