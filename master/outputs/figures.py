"""The paper's Figure 3, panel by panel, plus an animation of one trial.

(a) final drift per condition, (b, c) drift over time (sync, async), (d, e, f) the same for
the action: the held arm's force (top) and the paper's action measure, the horizontal hand
acceleration J a_dot (bottom; in (d) its mean over the trial, as the paper's Fig. 3 d),
(g) gamma over time, (h) the decoders' Jacobian images.

Each figure function returns its ``matplotlib.figure.Figure``, made with matplotlib's object API (no
pyplot, no backend switch: importing rhi leaves a notebook's plotting as it was); :func:`save` writes it.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rhi.master.outputs.files import atomic_write
from rhi.master.outputs.tables import cells, mean_sd

if TYPE_CHECKING:
    from matplotlib.figure import Figure  # matplotlib loads where a figure is drawn, not with the module

COLOURS = {"left": "tab:blue", "center": "tab:gray", "right": "tab:red"}
STYLES = {"conv": "-", "vae": "--"}
METADATA = {"Software": None}  # no version string in the file: same data, same bytes


def bars(axes, trials, per_trial, ylabel):
    """Mean +/- sd of a per-trial value (``per_trial[trial]``) per decoder, condition and stimulation,
    one axis of ``axes`` per stimulation; a cell with no trial (every one failed) has no bar."""
    found = cells(trials)
    decoders = list(dict.fromkeys(k[0] for k in found))
    conditions = list(dict.fromkeys(k[1] for k in found))
    stimulations = list(dict.fromkeys(k[2] for k in found))
    width = 0.8 / len(decoders)
    for axis, stimulation in zip(axes, stimulations):
        for d, decoder in enumerate(decoders):
            means, sds = zip(*(mean_sd(per_trial[found[(decoder, condition, stimulation)]])
                               if (decoder, condition, stimulation) in found else (np.nan, np.nan)
                               for condition in conditions))
            axis.bar(np.arange(len(conditions)) + (d - (len(decoders) - 1) / 2) * width, means, width,
                     yerr=sds, capsize=3, label=decoder, color=[COLOURS.get(c, "k") for c in conditions],
                     alpha=0.9 if d == 0 else 0.5, edgecolor="k")
        axis.axhline(0, color="k", lw=0.8)
        axis.set_xticks(range(len(conditions)), conditions)
        axis.set_title(stimulation)
    axes[0].set_ylabel(ylabel)
    axes[-1].legend(title="decoder (solid, faded)")


def subplots(*grid, **options):
    """A new ``Figure`` and its axes, as ``matplotlib.pyplot.subplots`` gives them, without pyplot's state."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=options.pop("figsize", None))
    return figure, figure.subplots(*grid, **options)


def final_bars(trials, values, ylabel) -> Figure:
    """Mean +/- sd of the end-of-trial value (``values[-1]``) per decoder, condition and stimulation."""
    columns = len(dict.fromkeys(t.stimulation for t in trials))
    figure, axes = subplots(1, columns, figsize=(4.5 * columns, 3.6), sharey=True, squeeze=False)
    bars(axes[0], trials, values[-1], ylabel)
    figure.tight_layout()
    return figure


def action_bars(trials, force, accel_mean) -> Figure:
    """Panel d: the final force (top row) and the action measure's trial mean (bottom row), per cell."""
    columns = len(dict.fromkeys(t.stimulation for t in trials))
    figure, axes = subplots(2, columns, figsize=(4.5 * columns, 6.6), sharey="row", squeeze=False)
    bars(axes[0], trials, force, "final horizontal force (N)")
    bars(axes[1], trials, accel_mean, "mean hand acceleration J a_dot (m/s$^2$)")
    figure.tight_layout()
    return figure


def lines_over_time(axis, trials, times, values, stimulation, ylabel):
    """Mean over trials (line) +/- sample sd (band) per decoder and condition, one stimulation."""
    for (decoder, condition, stim), members in cells(trials).items():
        if stim != stimulation:
            continue
        mean, sd = mean_sd(values[:, members], axis=1)
        axis.plot(times, mean, STYLES.get(decoder, ":"), color=COLOURS.get(condition, "k"),
                  label=f"{decoder} {condition}")
        axis.fill_between(times, mean - sd, mean + sd, color=COLOURS.get(condition, "k"), alpha=0.12)
    axis.axhline(0, color="k", lw=0.8)
    axis.set_xlabel("time (s)")
    axis.set_ylabel(ylabel)
    axis.set_title(stimulation)
    axis.legend(fontsize=7, ncol=2)


def over_time(trials, times, values, stimulation, ylabel) -> Figure:
    """Mean over trials (line) +/- sample sd (band) per decoder and condition, one stimulation."""
    figure, axis = subplots(figsize=(5.5, 3.6))
    lines_over_time(axis, trials, times, values, stimulation, ylabel)
    figure.tight_layout()
    return figure


def action_over_time(trials, times, force, accel, stimulation) -> Figure:
    """Panels e, f: the force (top) and the action measure J a_dot (bottom) over time, one stimulation."""
    figure, axes = subplots(2, 1, figsize=(5.5, 6.6), sharex=True)
    lines_over_time(axes[0], trials, times, force, stimulation, "horizontal force (N)")
    lines_over_time(axes[1], trials, times, accel, stimulation, "hand acceleration J a_dot (m/s$^2$)")
    axes[0].set_xlabel("")
    axes[1].set_title("")
    axes[1].get_legend().remove()
    figure.tight_layout()
    return figure


def jacobian_images(images: dict[str, np.ndarray]) -> Figure:
    """``images[decoder]`` has shape (2, H, W): d image / d shoulder and d image / d elbow (1/deg)."""
    figure, axes = subplots(len(images), 2, figsize=(6, 3 * len(images)), squeeze=False)
    for row, (decoder, pair) in enumerate(images.items()):
        for column, joint in enumerate(("shoulder", "elbow")):
            limit = float(np.abs(pair[column]).max()) or 1.0
            shown = axes[row, column].imshow(pair[column], cmap="RdBu_r", vmin=-limit, vmax=limit)
            axes[row, column].set_title(f"{decoder}: d g / d {joint}")
            axes[row, column].axis("off")
            figure.colorbar(shown, ax=axes[row, column], fraction=0.046)
    figure.tight_layout()
    return figure


def save(figure: Figure, path, dpi: int = 110) -> None:
    """Write ``figure`` to ``path`` (its format from the suffix, png without one) whole or not at all (a sweep's
    figures are rewritten in place)."""
    atomic_write(path, lambda file: figure.savefig(file, format=Path(path).suffix.lstrip(".") or "png", dpi=dpi,
                                                    metadata=METADATA))


def write_figure(path, function, *arguments) -> None:
    """Save ``function(*arguments)``'s figure to ``path``: one job of :func:`panel_jobs`, run on a worker."""
    save(function(*arguments), path)


def gamma_over_time(trials, times, gamma) -> Figure:
    """Panel g: gamma over time, the mean over each cell's trials, one axis per stimulation."""
    stimulations = list(dict.fromkeys(t.stimulation for t in trials))
    figure, axes = subplots(1, len(stimulations), figsize=(5 * len(stimulations), 3.4), squeeze=False)
    for axis, stimulation in zip(axes[0], stimulations):
        for (decoder, condition, stim), members in cells(trials).items():
            if stim == stimulation:
                axis.plot(times, gamma[:, members].mean(axis=1), STYLES.get(decoder, ":"),
                          color=COLOURS.get(condition, "k"), label=f"{decoder} {condition}")
        axis.set_ylim(0, 1.05)
        axis.set_xlabel("time (s)")
        axis.set_title(f"gamma, {stimulation}")
    axes[0, 0].set_ylabel("gamma")
    axes[0, -1].legend(fontsize=7, ncol=2)
    figure.tight_layout()
    return figure


def panel_jobs(folder: Path, trials, times, per_step: dict[str, np.ndarray], final: dict[str, np.ndarray],
               jacobians: dict | None) -> list[tuple]:
    """Every panel as a job ``(write_figure, path, figure function, *arguments)`` that writes one file of
    ``folder``: :func:`write_all` runs them in turn, the experiment on its workers (``rhi.master.runtime.pool.call``).

    per_step: the measures per step, (steps + 1, B); final: the per-trial values behind summary.csv
    (rhi.master.tasks.illusion.measures.end_of_trial), so the bars show exactly what the table reports.
    jacobians: the images of panel h (None: no panel h).
    """
    accel = per_step["action_accel_x_m_s2"]
    jobs = [(folder / "a_drift_final.png", final_bars, trials, per_step["drift_cm"], "final drift (cm)"),
            (folder / "d_force_final.png", action_bars, trials, final["force_x_n"],
             final["action_accel_mean_x_m_s2"])]
    for letter_drift, letter_force, stimulation in zip("bc", "ef", dict.fromkeys(t.stimulation for t in trials)):
        jobs += [(folder / f"{letter_drift}_drift_{stimulation}.png", over_time, trials, times, per_step["drift_cm"],
                  stimulation, "drift (cm)"),
                 (folder / f"{letter_force}_force_{stimulation}.png", action_over_time, trials, times,
                  per_step["force_x_n"], accel, stimulation)]
    jobs.append((folder / "g_gamma.png", gamma_over_time, trials, times, per_step["gamma"]))
    if jacobians:
        jobs.append((folder / "h_jacobians.png", jacobian_images, jacobians))
    return [(write_figure, *job) for job in jobs]


def write_all(folder: Path, trials, times, per_step: dict[str, np.ndarray], final: dict[str, np.ndarray],
              jacobians: dict | None) -> list[str]:
    """Write every panel of :func:`panel_jobs` into ``folder``; returns the file names."""
    folder.mkdir(parents=True, exist_ok=True)
    for function, *arguments in panel_jobs(folder, trials, times, per_step, final, jacobians):
        function(*arguments)
    return sorted(p.name for p in folder.iterdir())
