"""The paper's Figure 3, panel by panel, plus an animation of one trial.

(a) final drift per condition, (b, c) drift over time (sync, async), (d, e, f) the same for
the action: the held arm's force (top) and the paper's action measure, the horizontal hand
acceleration J a_dot (bottom; in (d) its mean over the trial, as the paper's Fig. 3 d),
(g) gamma over time, (h) the decoders' Jacobian images.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from rhi.master.outputs.files import atomic_write  # noqa: E402
from rhi.master.outputs.tables import cells, mean_sd  # noqa: E402

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


def final_bars(trials, values, ylabel, path):
    """Mean +/- sd of the end-of-trial value (``values[-1]``) per decoder, condition and stimulation."""
    columns = len(dict.fromkeys(t.stimulation for t in trials))
    figure, axes = plt.subplots(1, columns, figsize=(4.5 * columns, 3.6), sharey=True, squeeze=False)
    bars(axes[0], trials, values[-1], ylabel)
    save(figure, path)


def action_bars(trials, force, accel_mean, path):
    """Panel d: the final force (top row) and the action measure's trial mean (bottom row), per cell."""
    columns = len(dict.fromkeys(t.stimulation for t in trials))
    figure, axes = plt.subplots(2, columns, figsize=(4.5 * columns, 6.6), sharey="row", squeeze=False)
    bars(axes[0], trials, force, "final horizontal force (N)")
    bars(axes[1], trials, accel_mean, "mean hand acceleration J a_dot (m/s$^2$)")
    save(figure, path)


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


def over_time(trials, times, values, stimulation, ylabel, path):
    """Mean over trials (line) +/- sample sd (band) per decoder and condition, one stimulation."""
    figure, axis = plt.subplots(figsize=(5.5, 3.6))
    lines_over_time(axis, trials, times, values, stimulation, ylabel)
    save(figure, path)


def action_over_time(trials, times, force, accel, stimulation, path):
    """Panels e, f: the force (top) and the action measure J a_dot (bottom) over time, one stimulation."""
    figure, axes = plt.subplots(2, 1, figsize=(5.5, 6.6), sharex=True)
    lines_over_time(axes[0], trials, times, force, stimulation, "horizontal force (N)")
    lines_over_time(axes[1], trials, times, accel, stimulation, "hand acceleration J a_dot (m/s$^2$)")
    axes[0].set_xlabel("")
    axes[1].set_title("")
    axes[1].get_legend().remove()
    save(figure, path)


def jacobian_images(images: dict[str, np.ndarray], path):
    """``images[decoder]`` has shape (2, H, W): d image / d shoulder and d image / d elbow (1/deg)."""
    figure, axes = plt.subplots(len(images), 2, figsize=(6, 3 * len(images)), squeeze=False)
    for row, (decoder, pair) in enumerate(images.items()):
        for column, joint in enumerate(("shoulder", "elbow")):
            limit = float(np.abs(pair[column]).max()) or 1.0
            shown = axes[row, column].imshow(pair[column], cmap="RdBu_r", vmin=-limit, vmax=limit)
            axes[row, column].set_title(f"{decoder}: d g / d {joint}")
            axes[row, column].axis("off")
            figure.colorbar(shown, ax=axes[row, column], fraction=0.046)
    save(figure, path)


def save(figure, path):
    """Write the figure to ``path`` whole or not at all (a sweep's figures are rewritten in place)."""
    figure.tight_layout()
    try:
        atomic_write(path, lambda file: figure.savefig(file, format=Path(path).suffix.lstrip(".") or "png", dpi=110,
                                                        metadata=METADATA))
    finally:
        plt.close(figure)


def gamma_over_time(trials, times, gamma, path):
    """Panel g: gamma over time, the mean over each cell's trials, one axis per stimulation."""
    stimulations = list(dict.fromkeys(t.stimulation for t in trials))
    figure, axes = plt.subplots(1, len(stimulations), figsize=(5 * len(stimulations), 3.4), squeeze=False)
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
    save(figure, path)


def panel_jobs(folder: Path, trials, times, per_step: dict[str, np.ndarray], final: dict[str, np.ndarray],
               jacobians: dict | None) -> list[tuple]:
    """Every panel as a job ``(function, *arguments)`` that writes one file of ``folder``: :func:`write_all`
    runs them in turn, the experiment on its workers (``rhi.master.runtime.pool.call``).

    per_step: the measures per step, (steps + 1, B); final: the per-trial values behind summary.csv
    (rhi.master.tasks.illusion.measures.end_of_trial), so the bars show exactly what the table reports.
    jacobians: the images of panel h (None: no panel h).
    """
    accel = per_step["action_accel_x_m_s2"]
    jobs = [(final_bars, trials, per_step["drift_cm"], "final drift (cm)", folder / "a_drift_final.png"),
            (action_bars, trials, final["force_x_n"], final["action_accel_mean_x_m_s2"], folder / "d_force_final.png")]
    for letter_drift, letter_force, stimulation in zip("bc", "ef", dict.fromkeys(t.stimulation for t in trials)):
        jobs += [(over_time, trials, times, per_step["drift_cm"], stimulation, "drift (cm)",
                  folder / f"{letter_drift}_drift_{stimulation}.png"),
                 (action_over_time, trials, times, per_step["force_x_n"], accel, stimulation,
                  folder / f"{letter_force}_force_{stimulation}.png")]
    jobs.append((gamma_over_time, trials, times, per_step["gamma"], folder / "g_gamma.png"))
    if jacobians:
        jobs.append((jacobian_images, jacobians, folder / "h_jacobians.png"))
    return jobs


def write_all(folder: Path, trials, times, per_step: dict[str, np.ndarray], final: dict[str, np.ndarray],
              jacobians: dict | None) -> list[str]:
    """Write every panel of :func:`panel_jobs` into ``folder``; returns the file names."""
    folder.mkdir(parents=True, exist_ok=True)
    for function, *arguments in panel_jobs(folder, trials, times, per_step, final, jacobians):
        function(*arguments)
    return sorted(p.name for p in folder.iterdir())
