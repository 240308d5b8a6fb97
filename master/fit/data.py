"""The data a fit explains: FILE.csv, one row per participant x observation, read and checked.

Columns (docs/fit.md):

- ``participant``: any label;
- the design, one column of each pair: ``condition`` (a name of the configuration's ``[conditions]``) or
  ``offset_m`` (the rubber hand's lateral offset from the real hand, m); ``stimulation`` (a name of
  ``[stimulations]``) or ``delay_s`` (one fixed visuo-tactile delay after every touch, s); optionally
  ``time_s``, the trial's length (s), the same on every row;
- optionally ``protocol``, the protocol file (a configuration file, relative to the data file's folder) the row's
  study ran: rows of several protocols (other offsets, stroke rates, trial lengths, group sizes) are fitted in one fit,
  each protocol's cells simulated under its file's tables over the fit file's, its ``experiment.trials`` the group's
  n (else ``fit.trials_per_cell``); every participant (a group's label) must have rows in every protocol;
- optionally ``baseline``, a stimulation subtracted: the row's measures are the difference of its stimulation's and
  the baseline's (a within-participant contrast, ``sync`` minus ``async``, each participant their own baseline; its
  sd the sd of the differences), the design cell named ``sync-async``; empty where a row is no contrast;
- the observed measures, at least one: ``drift_cm`` and ``force_n`` (a trial outcome's final values), the drift
  read at times within the trial, ``drift_at_<t>s_cm`` (``drift_at_2s_cm``: a participant's pointing at 2 s; the
  fit reads the simulated drift then, ``experiment.probe_times``), and ``ownership_onset_s``, the time ownership
  first reached 1/2 (a model's own measure: only a model that records it can fit it);
- optionally, beside a measure, its between-participant sd ``drift_cm_sd`` (``force_n_sd``) or percentile
  ``ownership_onset_s_q90`` (two digits, 01-99): a group's row of a cell gives the group's mean and spread there,
  and a fit of group data simulates each draw as a study of ``fit.trials_per_cell`` participants of a
  ``[population]`` (docs/population.md), whose cell means, sds and percentiles are its statistics;
- optionally, beside two measures, a group's correlation of them over its participants per cell,
  ``r_drift_cm_vs_force_n`` (Pearson's r, in [-1, 1]);
- optionally, beside a measure, its noise column ``drift_cm_sem`` (``force_n_sem``): the standard error of the
  cell's value, in the measure's unit, the sd of the observation noise a fit adds to that cell's simulated mean
  in place of ``fit.noise.MEASURE`` (a group mean's reported SEM); one value per design cell, >= 0.

A line whose first cell starts with ``#`` is a comment (a source, a note), as is a blank line.

A participant's summary statistics are the mean of each measure over its rows in each design cell; every
participant must have every cell of the design. Any problem is a ConfigError naming the file, the line and
the column.
"""
from __future__ import annotations

import csv
import difflib
import io
import math
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rhi.master.cosim import ConfigError
from rhi.master.fit.columns import (COLUMNS, MEASURES, NUMERIC, correlation_of, is_measure, known_column,
                                    measure_order, noise_of, percentile_of, probe_time, spread_of)
from rhi.master.outputs.tables import probe_name

MAX_NOISE_SD = 1000.0  # a noise sd, fit.noise.MEASURE or a MEASURE_sem value, in the measure's unit: docs/safety.md
MAX_DATA_BYTES = 64 * 2**20  # a data file; a study's table is a few KiB


@dataclass(frozen=True)
class Data:
    """A checked data file: the design's cells and each participant's summary statistics."""

    path: str
    participants: list[str]                     # in the file's order of first appearance
    cells: list[tuple[str, str]]                # (condition, stimulation) names, sorted
    conditions: dict[str, float]                # offset_m columns' conditions: name -> offset (m); named: {}
    stimulations: dict[str, float]              # delay_s columns' stimulations: name -> fixed delay (s)
    measures: list[str]                         # observed measures, in measure_order
    observed: np.ndarray                        # (participants, cells x measures): cell means, cell-major
    counts: np.ndarray                          # (participants, cells): rows averaged per cell
    time_s: float | None                        # the trials' length, when the file gives it
    noise: dict[str, np.ndarray] = field(default_factory=dict)  # measure -> (cells,) sd of its MEASURE_sem column
    contrasts: dict[str, tuple[str, str]] = field(default_factory=dict)  # cell stimulation -> (stimulation, baseline)
    protocol: str | None = None                 # a part's protocol file, as the data give it (relative to the data)
    parts: tuple = ()                           # a file of several protocols: each protocol's Data, in file order

    def noise_sd(self, measures: list[str], default: dict[str, float]) -> np.ndarray:
        """The observation noise's sd of each statistic of ``measures``, cell-major as the statistics.

        Parameters
        ----------
        measures : list of str
            The fitted measures, in the statistics' order.
        default : dict of str to float
            Measure -> sd (``fit.noise.MEASURE``), for a measure without a noise column (0 if absent).

        Returns
        -------
        numpy.ndarray
            (cells x measures,): the row's ``MEASURE_sem`` where the data give it, else the default, in the
            measure's unit.
        """
        return np.array([self.noise[m][n] if m in self.noise else default.get(m, 0.0)
                         for n in range(len(self.cells)) for m in measures], dtype=float)

    def designs(self) -> tuple:
        """The data's parts, one per protocol (the data itself when it names none)."""
        return self.parts or (self,)

    def protocol_path(self) -> Path:
        """The part's protocol file, relative to the data file's folder."""
        return Path(self.path).parent / self.protocol

    def probe_times(self) -> list[float]:
        """The times (s) within the trial at which the data read the drift (their ``drift_at_<t>s_cm`` columns)."""
        return [probe_time(m) for m in self.measures if probe_time(m) is not None]

    def statistic_names(self) -> list[str]:
        """One name per column of ``observed``: ``drift_cm[left/sync]``."""
        return [f"{measure}[{condition}/{stimulation}]" for condition, stimulation in self.cells
                for measure in self.measures]


def offset_name(offset: float) -> str:
    """The condition a lateral offset defines: ``offset_-0.15_m``."""
    return f"offset_{offset:+.6g}_m"


def delay_name(delay: float) -> str:
    """The stimulation a fixed delay defines: ``delay_0.3_s``."""
    return f"delay_{delay:.6g}_s"


def read_data(path: str | Path) -> Data:
    """Read and check FILE.csv (module notes); a ConfigError names the first problem, with its line."""
    rows, header = read_rows(path)
    name = Path(path).name
    for column in header:
        base = column.removesuffix("_sd").removesuffix("_sem")
        if probe_time(base) is not None and probe_name(probe_time(base)) != base:
            raise ConfigError(f"{name}: column {column}: write the probe's time as {probe_name(probe_time(base))!r}, "
                              "the name of the measure a trial gives")
        if not known_column(column):
            close = difflib.get_close_matches(column, COLUMNS, n=1)
            raise ConfigError(f"{name}: unknown column {column!r}{f' (did you mean {close[0]!r}?)' if close else ''}; "
                              f"known: {', '.join(COLUMNS)}")
    if len(set(header)) != len(header):
        raise ConfigError(f"{name}: a column appears twice in the header")
    if "participant" not in header:
        raise ConfigError(f"{name}: no participant column")
    for pair in (("condition", "offset_m"), ("stimulation", "delay_s")):
        given = [c for c in pair if c in header]
        if len(given) != 1:
            raise ConfigError(f"{name}: give exactly one of the columns {pair[0]} and {pair[1]}, got "
                              f"{', '.join(given) or 'neither'}")
    if "baseline" in header and "stimulation" not in header:
        raise ConfigError(f"{name}: column baseline names a stimulation subtracted: give the stimulation column "
                          "(not delay_s) beside it")
    measures = measure_order(header)
    for column in header:
        if spread_of(column) is not None and spread_of(column) not in header:
            raise ConfigError(f"{name}: column {column} without its measure {spread_of(column)} (a group's "
                              "between-participant sd or percentile beside its mean)")
    for column in header:
        if correlation_of(column) is not None and not set(correlation_of(column)) <= set(header):
            raise ConfigError(f"{name}: column {column} without its measures {' and '.join(correlation_of(column))} "
                              "(a group's correlation of two measures beside their means)")
    for column in header:
        if noise_of(column) is not None and noise_of(column) not in header:
            raise ConfigError(f"{name}: column {column} without its measure {column.removesuffix('_sem')} (a noise "
                              "column gives the sd of that measure's observation noise)")
    if not any(is_measure(m) for m in measures):
        raise ConfigError(f"{name}: no measure column (drift_cm, the observed drift in cm, or another of "
                          f"{', '.join(MEASURES)})")
    if not rows:
        raise ConfigError(f"{name}: no data rows")
    values = []
    for line, row in rows:
        if len(row) != len(header):
            raise ConfigError(f"{name} line {line}: {len(row)} values for {len(header)} columns")
        record = {}
        for column, text in zip(header, row):
            text = text.strip()
            if column == "baseline" and not text:  # a row that is no contrast
                continue
            if not text:
                raise ConfigError(f"{name} line {line}: empty value in column {column}")
            if column in NUMERIC or is_measure(column) or spread_of(column) or noise_of(column) or correlation_of(column):
                try:
                    number = float(text)
                except ValueError:
                    raise ConfigError(f"{name} line {line}: column {column} = {text[:40]!r} is not a number") from None
                if not math.isfinite(number):
                    raise ConfigError(f"{name} line {line}: column {column} = {text[:40]!r} is not a finite number")
                if column in ("delay_s", "time_s") and not (number >= 0 if column == "delay_s" else number > 0):
                    raise ConfigError(f"{name} line {line}: column {column} = {text} must be "
                                      f"{'>= 0' if column == 'delay_s' else 'positive'}")
                if correlation_of(column) is not None and not -1 <= number <= 1:
                    raise ConfigError(f"{name} line {line}: column {column} = {text} is a correlation: it must lie in "
                                      "[-1, 1]")
                if spread_of(column) is not None and percentile_of(column) is None and number < 0:
                    raise ConfigError(f"{name} line {line}: column {column} = {text} is an sd: it must be >= 0")
                if noise_of(column) is not None and not 0 <= number <= MAX_NOISE_SD:
                    raise ConfigError(f"{name} line {line}: column {column} = {text} must be a standard error >= 0 "
                                      f"and at most {MAX_NOISE_SD:g} (in the measure's unit)")
                record[column] = number
            elif not text.isprintable():  # a line break, a tab, a control character: a name is one line of text
                raise ConfigError(f"{name} line {line}: column {column} = {text[:40]!r} holds a character that is not "
                                  "printable (a line break, a tab, a control character); a name is one line of text")
            else:
                record[column] = text
        if "protocol" in record and not (Path(path).parent / record["protocol"]).is_file():
            raise ConfigError(f"{name} line {line}: column protocol = {record['protocol'][:80]!r}: no such file "
                              f"(a protocol file's path is relative to the data file's folder)")
        if record.get("baseline") is not None and record["baseline"] == record["stimulation"]:
            raise ConfigError(f"{name} line {line}: column baseline = {record['baseline']!r} is the row's own "
                              "stimulation: a contrast subtracts another")
        values.append((line, record))
    return summarise(str(path), values, measures)


def read_rows(path: str | Path) -> tuple[list[tuple[int, list[str]]], list[str]]:
    """The header and the (line, values) of each non-blank row; a ConfigError for an unreadable file."""
    name = Path(path).name
    try:
        kind = os.stat(path).st_mode  # by its kind, before opening: a FIFO would wait for a writer forever
        if stat.S_ISDIR(kind):
            raise ConfigError(f"data file {path} is a folder, not a CSV file")
        if not stat.S_ISREG(kind):
            raise ConfigError(f"data file {path} is not a regular file (a FIFO, a device or a socket)")
        with open(path, "rb") as file:
            raw = file.read(MAX_DATA_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(f"data file {path} does not exist") from None
    except OSError as error:
        raise ConfigError(f"data file {path} cannot be read: {error.strerror or error}") from None
    if len(raw) > MAX_DATA_BYTES:
        raise ConfigError(f"data file {path} is over the limit of {MAX_DATA_BYTES} bytes")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise ConfigError(f"data file {path} is not UTF-8 text (byte at position {error.start})") from None
    try:  # each record with the line it starts on; a quoted value keeps its line breaks (read_data refuses them)
        reader, parsed, line = csv.reader(io.StringIO(text, newline="")), [], 1
        for row in reader:
            parsed.append((line, row))
            line = reader.line_num + 1
    except csv.Error as error:
        raise ConfigError(f"{name}: not a CSV file ({error})") from None
    numbered = [(line, row) for line, row in parsed
                if any(cell.strip() for cell in row) and not row[0].lstrip().startswith("#")]  # blank, comment
    if not numbered:
        raise ConfigError(f"{name}: empty (no header)")
    (_, header), *rows = numbered
    return rows, [column.strip() for column in header]


def summarise(path: str, values: list[tuple[int, dict]], measures: list[str]) -> Data:
    """Cell means per participant, each protocol's part apart when the rows name protocols (:func:`combined`)."""
    if "protocol" not in values[0][1]:
        return summarise_part(path, values, measures)
    protocols = list(dict.fromkeys(record["protocol"] for _, record in values))
    return combined(path, [summarise_part(path, [(line, record) for line, record in values
                                                 if record["protocol"] == protocol], measures, protocol)
                           for protocol in protocols])


def combined(path: str, parts: list[Data]) -> Data:
    """Several protocols' parts as one data set: their cells in turn, each condition named with its protocol
    (``rohde2011.toml:rohde``), the statistics concatenated cell-major; a ConfigError unless every part has the same
    participants."""
    name, first = Path(path).name, parts[0]
    for part in parts[1:]:
        if set(part.participants) != set(first.participants):
            other = sorted(set(part.participants) ^ set(first.participants))[0]
            raise ConfigError(f"{name}: participant {other} has no rows of protocol "
                              f"{(part if other in first.participants else first).protocol}; every participant "
                              "needs every protocol (a group fitted on several studies: one label on all their rows)")
    order = [[part.participants.index(p) for p in first.participants] for part in parts]
    noise = {m: np.concatenate([part.noise[m] for part in parts]) for m in first.noise}  # one header: all or none
    return Data(path, first.participants, [(f"{part.protocol}:{c}", s) for part in parts for c, s in part.cells],
                {}, {}, first.measures, np.concatenate([p.observed[o] for p, o in zip(parts, order)], axis=1),
                np.concatenate([p.counts[o] for p, o in zip(parts, order)], axis=1), None, noise, parts=tuple(parts))


def summarise_part(path: str, values: list[tuple[int, dict]], measures: list[str], protocol: str | None = None) -> Data:
    """Cell means per participant; a ConfigError for a participant lacking a cell or two trial lengths."""
    name = Path(path).name
    conditions, stimulations, contrasts, cell_of = {}, {}, {}, []
    for _, record in values:
        if "offset_m" in record:
            condition = offset_name(record["offset_m"])
            conditions[condition] = record["offset_m"]
        else:
            condition = record["condition"]
        if "delay_s" in record:
            stimulation = delay_name(record["delay_s"])
            stimulations[stimulation] = record["delay_s"]
        else:
            stimulation = record["stimulation"]
        if record.get("baseline") is not None:
            contrasts[f"{stimulation}-{record['baseline']}"] = (stimulation, record["baseline"])
            stimulation = f"{stimulation}-{record['baseline']}"
        cell_of.append((condition, stimulation))
    lengths = sorted({record["time_s"] for _, record in values if "time_s" in record})
    if len(lengths) > 1:
        raise ConfigError(f"{name}: column time_s has {len(lengths)} values ({', '.join(f'{t:g}' for t in lengths[:4])}"
                          f"{', ...' if len(lengths) > 4 else ''}){f' in protocol {protocol}' if protocol else ''}; "
                          "a protocol has one trial length (rows of other lengths name their protocol files)")
    participants = list(dict.fromkeys(record["participant"] for _, record in values))
    cells = sorted(set(cell_of))
    sums = np.zeros((len(participants), len(cells), len(measures)))
    counts = np.zeros((len(participants), len(cells)), dtype=int)
    where = {p: n for n, p in enumerate(participants)}
    column = {c: n for n, c in enumerate(cells)}
    for (_, record), cell in zip(values, cell_of):
        row, position = where[record["participant"]], column[cell]
        sums[row, position] += [record[m] for m in measures]
        counts[row, position] += 1
    for row, participant in enumerate(participants):
        missing = [f"{c}/{s}" for (c, s), count in zip(cells, counts[row]) if count == 0]
        if missing:
            raise ConfigError(f"{name}: participant {participant} has no row for the design cell {missing[0]}"
                              f"{f' (and {len(missing) - 1} more)' if len(missing) > 1 else ''}; every participant "
                              "needs every cell")
    observed = (sums / counts[:, :, None]).reshape(len(participants), -1)
    return Data(path, participants, cells, conditions, stimulations, measures, observed, counts,
                lengths[0] if lengths else None, cell_noise(name, values, cell_of, cells, measures), contrasts, protocol)


def cell_noise(name: str, values: list[tuple[int, dict]], cell_of: list, cells: list, measures: list[str]) -> dict:
    """Measure -> (cells,) the sd its ``MEASURE_sem`` column gives each design cell; a ConfigError where two rows of
    one cell (of any participants) give two values: a fit adds one noise per cell to every simulated participant."""
    noise = {}
    for measure in measures:
        column, given = f"{measure}_sem", {}
        if column not in values[0][1]:
            continue
        for (line, record), cell in zip(values, cell_of):
            if given.setdefault(cell, (record[column], line))[0] != record[column]:
                raise ConfigError(f"{name} line {line}: column {column} = {record[column]:g} differs from line "
                                  f"{given[cell][1]}'s {given[cell][0]:g} for the design cell {cell[0]}/{cell[1]}; "
                                  "a fit adds one noise sd per cell")
        noise[measure] = np.array([given[cell][0] for cell in cells])
    return noise


def check_against(data: Data, config: dict) -> None:
    """The named conditions and stimulations (a contrast's two) must exist in the fit's configuration."""
    name = Path(data.path).name
    for contrast in data.contrasts:
        if contrast in config["stimulations"]:
            raise ConfigError(f"{name}: the contrast {contrast} has the name of a stimulation of [stimulations]; "
                              "rename that stimulation")
    cells = [(c, s) for c, named in data.cells for s in data.contrasts.get(named, (named,))]
    for condition, stimulation in cells:
        if condition not in data.conditions and condition not in config["conditions"]:
            raise ConfigError(f"{name}: condition {condition!r} is not defined in [conditions] "
                              f"({', '.join(config['conditions'])}); give offset_m instead, or define it in the fit file")
        if stimulation not in data.stimulations and stimulation not in config["stimulations"]:
            raise ConfigError(f"{name}: stimulation {stimulation!r} is not defined in [stimulations] "
                              f"({', '.join(config['stimulations'])}); give delay_s instead, or define it in the fit file")
