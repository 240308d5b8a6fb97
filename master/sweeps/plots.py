"""Figures of a sweep: each measured outcome against each swept parameter, mean +/- sd.

One PNG per swept key, one panel per outcome (drift, force, final gamma, when present). A line
joins the points that differ only in that key, for one decoder x condition x stimulation.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from rhi.master.outputs.figures import save, subplots

if TYPE_CHECKING:
    from matplotlib.figure import Figure  # matplotlib loads where a figure is drawn, not with the module

OUTCOMES = {"drift_cm": "final drift (cm)", "force_n": "final force (N)", "gamma_final": "final gamma"}
MAX_LEGEND = 12


def is_number(value) -> bool:
    """Whether ``value`` is an int or a float (a bool is not)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def lines(key: str, keys: list[str], summary: list[dict]) -> dict[tuple, list[dict]]:
    """Rows grouped by everything but ``key``: cell and the other swept values."""
    found: dict[tuple, list[dict]] = {}
    for row in summary:
        others = tuple(json.dumps(row["parameters"].get(k)) for k in keys if k != key)
        found.setdefault((row["decoder"], row["condition"], row["stimulation"], others), []).append(row)
    return found


def plot_key(key: str, keys: list[str], summary: list[dict]) -> Figure | None:
    """Each outcome of ``summary`` against the swept ``key``, a panel per outcome and a line per cell and other
    swept values; None when no outcome is there."""
    outcomes = [o for o in OUTCOMES if any(row.get(f"{o}_mean") is not None for row in summary)]
    if not outcomes:
        return None
    values = list(dict.fromkeys(json.dumps(row["parameters"].get(key)) for row in summary))
    numeric = all(is_number(json.loads(v)) for v in values)
    position = {v: (json.loads(v) if numeric else i) for i, v in enumerate(values)}
    groups = lines(key, keys, summary)
    figure, axes = subplots(1, len(outcomes), figsize=(4.2 * len(outcomes), 3.4), squeeze=False)
    for axis, outcome in zip(axes[0], outcomes):
        for (decoder, condition, stimulation, others), rows in groups.items():
            rows = [r for r in rows if r.get(f"{outcome}_mean") is not None]
            if not rows:
                continue
            rows.sort(key=lambda r: position[json.dumps(r["parameters"].get(key))])
            name = " ".join([decoder, condition, stimulation, *others])
            axis.errorbar([position[json.dumps(r["parameters"].get(key))] for r in rows],
                          [r[f"{outcome}_mean"] for r in rows], yerr=[r[f"{outcome}_sd"] for r in rows],
                          marker="o", markersize=3, capsize=2, linewidth=1, label=name)
        axis.set_xlabel(key)
        axis.set_ylabel(OUTCOMES[outcome])
        if not numeric:
            axis.set_xticks(range(len(values)), [v.strip('"') for v in values], rotation=30, fontsize=7)
        axis.grid(alpha=0.3)
    if len(groups) <= MAX_LEGEND:
        axes[0][0].legend(fontsize=6)
    figure.suptitle(f"outcome against {key} (mean +/- sd over trials)", fontsize=9)
    figure.tight_layout()
    return figure


def plot_sweep(keys: list[str], summary: list[dict], folder: Path) -> None:
    """Write ``folder/KEY.png`` for each swept key that has an outcome to show."""
    folder.mkdir(exist_ok=True)
    for key in keys:
        figure = plot_key(key, keys, summary)
        if figure is not None:
            save(figure, folder / f"{key}.png")
