"""A fit's tables and figures: posterior samples, estimates, calibration, recovery, posterior predictive checks.

Every number is written with :func:`rhi.master.outputs.tables.number` (fixed formatting: the same numbers, the same
bytes); every file whole or absent (atomic writes).
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rhi.master.fit.calibration import LEVELS, central_interval, rank_histogram, rank_tests_verdict, verdict_words
from rhi.master.fit.plan import Parameter
from rhi.master.outputs.figures import subplots
from rhi.master.outputs.files import atomic_write
from rhi.master.outputs.tables import csv_text, number

if TYPE_CHECKING:
    from matplotlib.figure import Figure  # matplotlib loads where a figure is drawn, not with the module

FIGURE_DPI = 100  # the fit's figures' resolution (rhi.master.outputs.figures.save's dpi)

# column -> meaning, for docs/fit.md (each file's columns)
ESTIMATE_COLUMNS = {"participant": "the participant's label", "parameter": "the fitted parameter's key",
                    "median": "posterior median, in the key's unit", "q05": "5th percentile (the 90 % interval's "
                    "low end)", "q95": "95th percentile", "q25": "25th percentile", "q75": "75th percentile"}
CALIBRATION_COLUMNS = {
    "parameter": "the fitted parameter's key", "held_out": "held-out simulated participants",
    "correlation": "Pearson's r of the true values and the posterior medians (in the inference space: the "
                   "logarithm of a log-uniform parameter)",
    "sd_ratio": "mean posterior sd / the prior's sd over the held-out participants (near 1: not identified)",
    "coverage_50": "share of true values inside the central 50 % interval (read off the ranks)",
    "coverage_90": "share of true values inside the central 90 % interval (read off the ranks)",
    "sbc_bins": "bins of the SBC rank histogram", "sbc_chisquare": "chi-square statistic of the histogram against "
    "the uniform", "sbc_chisquare_p": "its p-value (scipy.stats.chisquare)",
    "sbc_ks": "Kolmogorov-Smirnov statistic of the scaled ranks against U(0, 1)",
    "sbc_ks_p": "its p-value (scipy.stats.kstest)"}


def natural(parameters: list[Parameter], inference: np.ndarray) -> np.ndarray:
    """Samples (..., parameters) from the inference space to the parameters' own units."""
    return np.stack([p.from_inference(inference[..., d]) for d, p in enumerate(parameters)], axis=-1)


def posterior_csv(parameters: list[Parameter], participants: list[str], samples: np.ndarray) -> str:
    """samples: (participants, L, parameters) in the parameters' units."""
    rows = [[participant, index, *(number(v) for v in sample)] for participant, block in zip(participants, samples)
            for index, sample in enumerate(block)]
    return csv_text(["participant", "sample", *(p.key for p in parameters)], rows)


def estimates_csv(parameters: list[Parameter], participants: list[str], samples: np.ndarray) -> str:
    """estimates.csv: per participant and parameter, the posterior median, 5th, 95th, 25th and 75th percentile.

    Parameters
    ----------
    parameters : list of Parameter
        The fitted parameters, in the samples' last axis' order.
    participants : list of str
        The participants' labels.
    samples : numpy.ndarray
        (participants, L, parameters) posterior samples, in the parameters' own units.

    Returns
    -------
    str
        The CSV text, columns ``ESTIMATE_COLUMNS``.
    """
    rows = []
    for participant, block in zip(participants, samples):
        for d, parameter in enumerate(parameters):
            q = np.quantile(block[:, d], (0.5, 0.05, 0.95, 0.25, 0.75))
            rows.append([participant, parameter.key, *(number(v) for v in q)])
    return csv_text(list(ESTIMATE_COLUMNS), rows)


def calibration_csv(parameters: list[Parameter], result: dict) -> str:
    """calibration.csv: per parameter, the recovery (r, sd ratio), the coverage and the SBC rank tests of ``result``
    (``rhi.master.fit.calibration.calibrate``'s), columns ``CALIBRATION_COLUMNS``."""
    u, r = result["uniformity"], result["recovery"]
    rows = [[p.key, result["participants"], number(r["correlation"][d]), number(r["sd_ratio"][d]),
             number(result["coverage"][0.5][d]), number(result["coverage"][0.9][d]), u["bins"],
             number(u["chisquare"][d]), number(u["chisquare_p"][d]), number(u["ks"][d]), number(u["ks_p"][d])]
            for d, p in enumerate(parameters)]
    return csv_text(list(CALIBRATION_COLUMNS), rows)


def recovery_csv(parameters: list[Parameter], truths: np.ndarray, samples: np.ndarray, ranks: np.ndarray) -> str:
    """One row per held-out participant: true value, posterior median and 90 % interval, rank, per parameter
    (parameters' units)."""
    low, high = central_interval(samples, 0.9, axis=1)
    median = np.median(samples, axis=1)
    header = ["held_out", *(f"{p.key}{suffix}" for p in parameters
                            for suffix in ("_true", "_median", "_q05", "_q95", "_rank"))]
    rows = [[n, *(x for d in range(len(parameters)) for x in (number(truths[n, d]), number(median[n, d]),
                                                              number(low[n, d]), number(high[n, d]), ranks[n, d]))]
            for n in range(len(truths))]
    return csv_text(header, rows)


def calibration_figure(parameters: list[Parameter], result: dict, truths: np.ndarray) -> Figure:
    """Per parameter: the SBC rank histogram with the uniform's 99 % band, and true value against median."""
    count, samples = result["participants"], result["samples"]
    bins = result["uniformity"]["bins"]
    counts = rank_histogram(result["ranks"], samples, bins)
    fig, axes = subplots(2, len(parameters), figsize=(3.6 * len(parameters), 6.4), squeeze=False)
    from scipy import stats

    expected = count / bins
    band = stats.binom.interval(0.99, count, 1 / bins)
    for d, parameter in enumerate(parameters):
        axis = axes[0, d]
        axis.bar(np.arange(bins), counts[:, d], width=0.9, color="tab:blue")
        axis.axhspan(*band, color="gray", alpha=0.2, label="uniform, 99 %")
        axis.axhline(expected, color="k", lw=0.8)
        axis.set_title(f"{parameter.key}\nSBC p = {result['uniformity']['chisquare_p'][d]:.2f} (chi-square)",
                       fontsize=8)
        axis.set_xlabel(f"rank bin ({samples + 1} ranks in {bins} bins)", fontsize=8)
        axis = axes[1, d]
        medians = result["recovery"]["medians"][:, d]
        axis.plot(truths[:, d], medians, "o", ms=3)
        ends = [min(truths[:, d].min(), medians.min()), max(truths[:, d].max(), medians.max())]
        axis.plot(ends, ends, "k-", lw=0.8)
        axis.set_xlabel(f"true{' (log)' if parameter.log else ''}", fontsize=8)
        axis.set_ylabel("posterior median", fontsize=8)
        axis.set_title(f"r = {result['recovery']['correlation'][d]:.3f}, 90 % coverage "
                       f"{result['coverage'][0.9][d]:.2f}", fontsize=8)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"rhi fit: calibration on {count} held-out simulated participants", fontsize=10)
    fig.tight_layout()
    return fig


def predictive_figure(names: list[str], participants: list[str], observed: np.ndarray,
                      predicted: np.ndarray) -> Figure:
    """Per participant (a panel each): the observed statistics and the posterior predictive's median and 90 %
    interval. observed: (participants, statistics); predicted: (participants, draws, statistics)."""
    count = len(participants)
    columns = min(4, count)
    rows = -(-count // columns)
    fig, axes = subplots(rows, columns, figsize=(max(6.5, 4.2 * columns), 3.2 * rows + 0.6), squeeze=False)
    positions = np.arange(len(names))
    for n, (participant, axis) in enumerate(zip(participants, axes.flat)):
        draws = predicted[n][np.all(np.isfinite(predicted[n]), axis=1)]
        if len(draws):
            low, high = central_interval(draws, 0.9, axis=0)
            axis.fill_between(positions, low, high, color="tab:blue", alpha=0.25, step="mid",
                              label="posterior predictive, 90 %")
            axis.plot(positions, np.median(draws, axis=0), "_", color="tab:blue", ms=14, mew=2, label="its median")
        axis.plot(positions, observed[n], "o", color="k", ms=4, label="data")
        axis.set_xticks(positions, names, rotation=60, ha="right", fontsize=6)
        axis.axhline(0, color="k", lw=0.5)
        axis.set_title(f"participant {participant} ({len(draws)} draws)", fontsize=8)
        axis.grid(alpha=0.3)
    for axis in list(axes.flat)[count:]:
        axis.axis("off")
    axes[0, 0].legend(fontsize=6)
    fig.suptitle("rhi fit: posterior predictive check (each statistic in its measure's unit)", fontsize=10)
    fig.tight_layout()
    return fig


def predictive_csv(names: list[str], participants: list[str], observed: np.ndarray, predicted: np.ndarray) -> str:
    """predictive.csv: per participant and statistic, the observed value and the posterior predictive's median and
    90 % interval over its finite draws.

    Parameters
    ----------
    names : list of str
        The statistics' names.
    participants : list of str
        The participants' labels.
    observed : numpy.ndarray
        (participants, statistics), each statistic in its measure's unit.
    predicted : numpy.ndarray
        (participants, draws, statistics), the same units; a draw with a non-finite value is left out.

    Returns
    -------
    str
        The CSV text.
    """
    rows = []
    for n, participant in enumerate(participants):
        draws = predicted[n][np.all(np.isfinite(predicted[n]), axis=1)]
        for s, name in enumerate(names):
            q = np.quantile(draws[:, s], (0.5, 0.05, 0.95)) if len(draws) else [np.nan] * 3
            rows.append([participant, name, number(observed[n, s]), len(draws), *(number(v) for v in q)])
    return csv_text(["participant", "statistic", "observed", "draws", "predicted_median", "predicted_q05",
                     "predicted_q95"], rows)


def write_table(path: Path, text: str) -> None:
    """Write ``text`` to ``path``, atomically."""
    atomic_write(path, text)


__all__ = ["LEVELS", "natural", "posterior_csv", "estimates_csv", "calibration_csv", "recovery_csv",
           "calibration_figure", "predictive_figure", "predictive_csv"]


def verdict_row(rows: list[dict]) -> str:
    """The measures table's row of :func:`rank_tests_verdict`, from calibration.csv's rows."""
    verdict = rank_tests_verdict([float(r["sbc_chisquare_p"]) for r in rows], [float(r["sbc_ks_p"]) for r in rows])
    return f"| SBC rank tests as one family (Bonferroni, α = {verdict['alpha']:g}) | {verdict_words(verdict)} |"


def results_markdown(out: Path) -> str:
    """A fit's calibration and timing as Markdown tables, from its own files (calibration.csv, run.json):
    what docs/fit.md shows of a measured fit."""
    import csv
    import json

    run = json.loads((out / "run.json").read_text())
    with open(out / "calibration.csv", newline="") as file:
        rows = list(csv.DictReader(file))
    lines = ["| parameter | prior | r (true, median) | posterior sd / prior sd | 50 % coverage | 90 % coverage | "
             "SBC chi-square p | SBC KS p |", "|---|---|---|---|---|---|---|---|"]
    priors = {p["key"]: p for p in run["parameters"]}
    for row in rows:
        prior = priors[row["parameter"]]
        bounds = f"{prior['prior']} [{prior.get('low', '-inf')}, {prior.get('high', 'inf')}]"
        lines.append(f"| `{row['parameter']}` | {bounds} | {float(row['correlation']):.3f} | "
                     f"{float(row['sd_ratio']):.2f} | {float(row['coverage_50']):.2f} | {float(row['coverage_90']):.2f} | "
                     f"{float(row['sbc_chisquare_p']):.3f} | {float(row['sbc_ks_p']):.3f} |")
    simulations, estimator = run["simulations"], run["estimator"]
    timing = run["posterior_seconds_per_participant"]
    lines += ["", "| measure | value |", "|---|---|",
              verdict_row(rows),
              f"| simulated participants (trials) | {simulations['participants']} ({simulations['trials']}, "
              f"{simulations['steps_per_trial']} steps at {simulations['resolution']}x{simulations['resolution']}) |",
              f"| held out for the calibration | {run['calibration']['held_out']} "
              f"(L = {run['calibration']['samples_per_participant']}"
              + ("; a Latin hypercube" if run["settings"].get("calibration_design") == "latin-hypercube" else "")
              + ") |",
              f"| failed simulated participants | {simulations['failed_participants']} |",
              f"| simulations' wall time | {simulations['wall_s_now']:.0f} s "
              + (f"({simulations['trials_per_s_now']} trials/s) |" if simulations['trials_per_s_now'] is not None
                 else "(none run: an earlier run's simulations) |"),
              f"| workers' CPU time per trial | {simulations['cpu_s_per_trial']:.3f} s |",
              f"| training | {estimator['seconds']:.1f} s, "
              + (f"{estimator['epochs']} epochs" if estimator.get("ensemble", 1) == 1 else
                 f"an ensemble of {estimator['ensemble']} ({', '.join(map(str, estimator['members']))} epochs)")
              + f", {estimator['density']} ({estimator['hidden_features']} hidden, {estimator['transforms']} transforms"
              + (", unconstrained space" if estimator.get("space") == "unconstrained" else "")
              + (", normal scores" if estimator.get("statistics") == "normal-scores" else "") + "), "
              f"{estimator['torch_threads']} torch threads |",
              f"| posterior of a participant ({run['settings']['posterior_samples']} samples) | "
              f"{timing['mean']:.3f} s mean, {timing['max']:.3f} s max |",
              f"| whole fit | {run['wall_s']:.0f} s |",
              f"| CPU | {run['versions']['cpu']['model']} |"]
    return "\n".join(lines) + "\n"
