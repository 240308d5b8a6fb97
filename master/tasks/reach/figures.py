"""`rhi reach`'s figures: the hand's paths, the distance to the goal over time, and success against the goal's
distance (docs/reach.md); each function returns its ``Figure`` (:mod:`rhi.master.outputs.figures`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from matplotlib.figure import Figure

from rhi.master.outputs.figures import save, subplots
from rhi.master.outputs.tables import cells

BAND_COLOURS = {"near": "tab:blue", "far": "tab:orange"}


def colour(band: str) -> str:
    """The band's colour in every figure (purple for a band other than near and far)."""
    return BAND_COLOURS.get(band, "tab:purple")


def paths(trials, per_step, final) -> Figure:
    """The hand's path of every reach, per decoder; a cross at each goal hand, green if reached, red if not."""
    decoders = list(dict.fromkeys(t.decoder for t in trials))
    figure, axes = subplots(1, len(decoders), figsize=(5 * len(decoders), 4.6), squeeze=False)
    for axis, decoder in zip(axes[0], decoders):
        for i, trial in enumerate(trials):
            if trial.decoder != decoder:
                continue
            x, y = 100 * per_step["hand_x_m"][:, i], 100 * per_step["hand_y_m"][:, i]
            reached = bool(final["reached"][i])
            axis.plot(x, y, color=colour(trial.band), lw=0.7, alpha=0.8)
            axis.plot(*goal_hand(per_step, i), marker="x", ms=5, color="tab:green" if reached else "tab:red")
        axis.plot(100 * per_step["hand_x_m"][0, 0], 100 * per_step["hand_y_m"][0, 0], "ko", ms=4)
        axis.set_title(f"{decoder}: hand paths (x: goal; green reached)")
        axis.set_xlabel("hand x (cm)")
        axis.set_ylabel("hand y (cm)")
        axis.set_aspect("equal", adjustable="datalim")
    figure.tight_layout()
    return figure


def goal_hand(per_step, trial: int) -> tuple[float, float]:
    """The goal hand (cm) of ``trial``."""
    return 100 * per_step["goal_x_m"][0, trial], 100 * per_step["goal_y_m"][0, trial]


def error_over_time(trials, times, per_step, radius_cm) -> Figure:
    """The hand's distance to the goal over time, per decoder: every reach thin, each band's median thick."""
    decoders = list(dict.fromkeys(t.decoder for t in trials))
    figure, axes = subplots(1, len(decoders), figsize=(5 * len(decoders), 3.6), squeeze=False, sharey=True)
    for axis, decoder in zip(axes[0], decoders):
        for (who, band), members in cells(trials, key=lambda t: (t.decoder, t.band)).items():
            if who != decoder:
                continue
            distance = per_step["distance_cm"][:, members]
            axis.plot(times, distance, color=colour(band), lw=0.3, alpha=0.4)
            axis.plot(times, np.median(distance, axis=1), color=colour(band), lw=2, label=f"{band} (median)")
        axis.axhline(radius_cm, color="k", ls=":", lw=1, label=f"success radius {radius_cm:g} cm")
        axis.set_title(decoder)
        axis.set_xlabel("time (s)")
        axis.set_yscale("log")
        axis.legend(fontsize="small")
    axes[0, 0].set_ylabel("hand to goal hand (cm)")
    figure.tight_layout()
    return figure


def success_vs_distance(trials, final, radius_cm) -> Figure:
    """Final against starting distance of every reach, per decoder; below the dotted line: reached; above the
    diagonal: ended farther from the goal than it started."""
    decoders = list(dict.fromkeys(t.decoder for t in trials))
    figure, axes = subplots(1, len(decoders), figsize=(5 * len(decoders), 4), squeeze=False, sharey=True)
    start, end = final["start_distance_cm"], final["final_distance_cm"]
    top = float(max(np.max(start), np.max(end), radius_cm)) * 1.1
    for axis, decoder in zip(axes[0], decoders):
        for band in dict.fromkeys(t.band for t in trials):
            members = [i for i, t in enumerate(trials) if t.decoder == decoder and t.band == band]
            reached = int(np.sum(final["reached"][members]))
            axis.scatter(start[members], end[members], s=14, color=colour(band),
                         label=f"{band}: {reached}/{len(members)} reached")
        axis.plot([0, top], [0, top], color="gray", lw=0.8, label="as far as at the start")
        axis.axhline(radius_cm, color="k", ls=":", lw=1, label=f"radius {radius_cm:g} cm")
        axis.set_yscale("symlog", linthresh=radius_cm)
        axis.set_title(decoder)
        axis.set_xlabel("goal's distance at the start (cm)")
        axis.legend(fontsize="small")
    axes[0, 0].set_ylabel("final distance (cm)")
    figure.tight_layout()
    return figure


def write_figures(folder: Path, trials, times, per_step, final, radius_cm) -> None:
    """Write paths.png, error_over_time.png and success_vs_distance.png into ``folder``.

    Parameters
    ----------
    folder : Path
        The figures' folder, existing.
    trials : list of ReachTrial
        The B reaches, in the arrays' column order.
    times : numpy.ndarray
        (steps + 1,) s.
    per_step : dict of str to numpy.ndarray
        (steps + 1, B) each, ``rhi.master.tasks.reach.task.measures``: hand and goal in m, distances in cm.
    final : dict of str to numpy.ndarray
        (B,) each, ``rhi.master.tasks.reach.task.outcomes``: distances in cm, reached.
    radius_cm : float
        The success radius, cm.
    """
    save(paths(trials, per_step, final), folder / "paths.png")
    save(error_over_time(trials, times, per_step, radius_cm), folder / "error_over_time.png")
    save(success_vs_distance(trials, final, radius_cm), folder / "success_vs_distance.png")
