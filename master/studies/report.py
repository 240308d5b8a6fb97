"""``rhi power``'s folder: power.csv (the curve with its Monte Carlo error), power.png, run.json; whole or not at
all."""
from __future__ import annotations


from matplotlib.figure import Figure

from rhi.master import models
from rhi.master.cosim import ConfigError
from rhi.master.outputs.files import atomic_write, output_folder
from rhi.master.outputs.provenance import package_versions, write_run_record
from rhi.master.outputs.tables import csv_text, number

METADATA = {"Software": None}  # no version string in the file: same data, same bytes
# The end-of-trial measures every model has (master/tasks/illusion/measures.py); a model adds its own.
MEASURES = ("drift_cm", "force_x_n", "gamma", "action_accel_x_m_s2", "action_accel_mean_x_m_s2", "drift_half_time_s")


def check_measure(measure: str, config: dict) -> None:
    """ConfigError unless ``measure`` is an end-of-trial measure of the configuration's model."""
    known = (*MEASURES, *models.of(config).measures)
    if measure not in known:
        raise ConfigError(f"--measure {measure!r} is not an end-of-trial measure (one of {', '.join(known)})")


def table(curve, measure: str) -> str:
    """power.csv: per study size, the power, its Monte Carlo standard error, and the contrast's mean and
    between-participant sd of the difference (in the measure's unit)."""
    return csv_text(["n_participants", "studies", "power", "power_mc_error", f"mean_difference_{measure}",
                     f"sd_difference_{measure}"],
                    [[point.n, point.studies, number(point.power), number(point.mc_error),
                      number(point.mean_difference), number(point.sd_difference)] for point in curve])


def figure(curve, alpha: float, contrast: str) -> Figure:
    """The power curve, each point with +/- 1 Monte Carlo standard error, and the conventional 80 % line."""
    drawn = Figure(figsize=(4.5, 3.4))
    axis = drawn.subplots()
    axis.errorbar([p.n for p in curve], [p.power for p in curve], yerr=[p.mc_error for p in curve], marker="o",
                  capsize=3)
    axis.axhline(0.8, color="0.6", lw=0.8, ls="--")
    axis.set_ylim(-0.02, 1.02)
    axis.set_xlabel("participants per study")
    axis.set_ylabel(f"power (paired t, alpha = {alpha:g})")
    axis.set_title(f"{contrast}: +/- 1 Monte Carlo s.e.", fontsize=9)
    drawn.tight_layout()
    return drawn


def write(out, curve, config: dict, arguments: dict, force: bool, seconds: float) -> None:
    """DIR: power.csv, power.png and run.json (the configuration, the command's arguments, versions, time)."""
    measure = arguments["measure"]
    with output_folder(out, force) as staging:
        atomic_write(staging / "power.csv", table(curve, measure))
        drawn = figure(curve, arguments["alpha"], arguments["contrast"])
        atomic_write(staging / "power.png", lambda file: drawn.savefig(file, format="png", dpi=110, metadata=METADATA))
        provenance = {"command": "rhi power", "model": models.of(config).name, "configuration": config,
                      "arguments": {key: value for key, value in arguments.items() if key != "run"},
                      "versions": package_versions(), "timings_s": {"total": seconds}}
        write_run_record(staging, provenance)
