"""The columns of a fit's data file by name: the measures a fit can explain, their spreads, percentiles,
correlations and noise columns, and the design's columns (docs/fit.md, "The data file"; read by
:mod:`rhi.master.fit.data`)."""
from __future__ import annotations

import re

MEASURES = ("drift_cm", "force_n", "ownership_onset_s")  # observed measures a fit can explain: trial outcomes
MODEL_MEASURES = ("ownership_onset_s",)  # of these, a model's own (Model.measures): the fit's model must record it
EVENT_TIMES = ("ownership_onset_s",)  # times of an event a participant may never reach: NaN is "not within the trial"
NOISE = tuple(f"{measure}_sem" for measure in MEASURES)  # each measure's per-cell noise sd (its standard error)
SPREADS = tuple(f"{measure}_sd" for measure in MEASURES)  # a group's between-participant sd of the measure per cell
PERCENTILE = re.compile(r"(.+)_q(0[1-9]|[1-9][0-9])")  # a group's percentile of a measure per cell: ownership_onset_s_q90
CORRELATION = re.compile(r"r_(.+)_vs_(.+)")  # a group's correlation of two measures over its participants per cell
DESIGN = ("protocol", "condition", "offset_m", "stimulation", "baseline", "delay_s", "time_s")
COLUMNS = ("participant", *DESIGN, *MEASURES, *SPREADS, *NOISE)
NUMERIC = ("offset_m", "delay_s", "time_s", *MEASURES, *SPREADS, *NOISE)
PROBE = re.compile(r"drift_at_(\d+(?:\.\d+)?)s_cm")  # the drift read at a time within the trial: probe_name


def probe_time(column: str) -> float | None:
    """The time (s) a probe measure's column reads the drift at (``drift_at_2s_cm``: 2.0), else None."""
    found = PROBE.fullmatch(column)
    return float(found.group(1)) if found else None


def is_measure(column: str) -> bool:
    """A measure a fit can explain: one of :data:`MEASURES` or a probe of the drift (``drift_at_2s_cm``)."""
    return column in MEASURES or probe_time(column) is not None


def spread_of(column: str) -> str | None:
    """The measure whose between-participant sd or percentile the column gives (``drift_cm_sd``,
    ``drift_cm_q90``: ``drift_cm``), else None."""
    base = column.removesuffix("_sd")
    if base == column and PERCENTILE.fullmatch(column):
        base = PERCENTILE.fullmatch(column).group(1)
    return base if base != column and is_measure(base) else None


def correlation_of(column: str) -> tuple[str, str] | None:
    """The two measures whose correlation over a group's participants the column gives (``r_drift_cm_vs_force_n``:
    ``("drift_cm", "force_n")``), else None."""
    found = CORRELATION.fullmatch(column)
    return (found.group(1), found.group(2)) if found and all(map(is_measure, found.groups())) else None


def measures_of(column: str) -> tuple[str, ...]:
    """The measures a statistic's column is made of: a correlation's two, a spread's or percentile's one, a
    measure itself."""
    return correlation_of(column) or ((spread_of(column) or column),)


def percentile_of(column: str) -> int | None:
    """The percentile a group's column gives (``ownership_onset_s_q90``: 90), else None."""
    found = PERCENTILE.fullmatch(column)
    return int(found.group(2)) if found and is_measure(found.group(1)) else None


def noise_of(column: str) -> str | None:
    """The measure whose observation noise's sd the column gives (``drift_cm_sem``: ``drift_cm``), else None."""
    base = column.removesuffix("_sem")
    return base if base != column and is_measure(base) else None


def measure_order(columns) -> list[str]:
    """The measures and spreads among ``columns`` in the statistics' order: :data:`MEASURES`, the probes by time,
    then the sds in the same order, then the percentiles (by measure, then percentile), then the correlations."""
    means = [m for m in MEASURES if m in columns] + sorted((c for c in columns if probe_time(c) is not None),
                                                           key=probe_time)
    percentiles = sorted((c for c in columns if percentile_of(c) is not None),
                         key=lambda c: (means.index(spread_of(c)) if spread_of(c) in means else len(means),
                                        percentile_of(c)))
    correlations = sorted(c for c in columns if correlation_of(c) is not None)
    return means + [f"{m}_sd" for m in means if f"{m}_sd" in columns] + percentiles + correlations


def known_column(column: str) -> bool:
    """A column read_data knows: :data:`COLUMNS`, a probe measure, its sd or its noise column."""
    return (column in COLUMNS or is_measure(column) or spread_of(column) is not None or noise_of(column) is not None
            or correlation_of(column) is not None)
