"""The human-phenomena protocols: the shipped files, the report by hand, and each command end to end at
quick size (the session's --quick decoders, two points, a few seconds of trial, on one shared Dask worker)."""
import csv
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from rhi.master.commands.cli import main
from rhi.master.cosim import ConfigError
from rhi.master.phenomena import FILES, NAMES, human_file, sweep_file
from rhi.master.phenomena import report as reports
from rhi.master.sweeps import plan as sweeps
from tests.sweep_files import ENV, dask_cluster_at


def to_toml(table: dict, prefix: str = "") -> str:
    """Enough of a TOML writer for sweep files: scalars, lists, inline and nested tables, arrays of tables."""
    def value(v):
        if isinstance(v, dict):
            return "{ " + ", ".join(f'"{k}" = {value(x)}' for k, x in v.items()) + " }"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return json.dumps(v)
    plain = [f'"{k}" = {value(v)}' for k, v in table.items()
             if not isinstance(v, dict) and not (isinstance(v, list) and v and isinstance(v[0], dict))]
    text = [f"[{prefix}]"] * bool(prefix and plain) + plain
    for key, v in table.items():
        if isinstance(v, dict):
            text.append(to_toml(v, f"{prefix}.{key}" if prefix else key))
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            for item in v:
                text += [f"[[{prefix}.{key}]]" if prefix else f"[[{key}]]",
                         *(f'"{k}" = {value(x)}' for k, x in item.items())]
    return "\n".join(text)


def shipped(name: str) -> dict:
    with open(sweep_file(name), "rb") as file:
        return tomllib.load(file)


@pytest.fixture(scope="module")
def one_worker(quick_cache, tmp_path_factory):
    """A Dask scheduler and one worker shared by the protocols' runs (a local pool each would start its own)."""
    with dask_cluster_at(tmp_path_factory.mktemp("cluster"), workers=1,
                         env={**ENV, "RHI_CACHE": str(quick_cache)}) as address:
        yield address


def test_shipped_files_load_and_span_the_human_ranges():
    spans = {}
    for name in NAMES:
        sweep = sweeps.load(sweep_file(name))  # every point's configuration is valid
        phenomenon = reports.PHENOMENA[name]
        assert phenomenon.file == FILES[name] and sweep_file(name).name == FILES[name]
        xs = sorted({phenomenon.x_of(sweep.configs[t.point], t.condition, t.stimulation) for t in sweep.trials})
        spans[name] = (xs[0], xs[-1], len(xs))
        assert all(config["decoder"]["fast"] for config in sweep.configs)  # fast mode, as docs/phenomena.md says
    assert spans == {"temporal-window": (0.0, 1.0, 13), "distance": (5.0, 60.0, 12), "time-course": (5.0, 30.0, 6),
                     "persistence": (30.0, 90.0, 5), "vision-only": (0.0, 2.0, 3),
                     "blocks": (10.0, 120.0, 3)}
    # the fixed delay: delay_min = delay_max at every point
    for config in sweeps.load(sweep_file("temporal-window")).configs:
        assert config["stimulations"]["fixed"]["delay_min"] == config["stimulations"]["fixed"]["delay_max"]


def test_the_spatial_variant_of_the_distance_protocol():
    """distance_spatial.toml: the distance points with causal inference over space on, and nothing else changed."""
    spatial = sweeps.load(sweep_file("distance").with_name("distance_spatial.toml"))
    plain = sweeps.load(sweep_file("distance"))
    assert spatial.points == plain.points and {c["brain"]["spatial_sd"] for c in spatial.configs} == {0.18}
    for a, b in zip(spatial.configs, plain.configs):
        assert {**a, "brain": {**a["brain"], "spatial_sd": None}} == {**b, "brain": {**b["brain"], "spatial_sd": None}}


def test_human_file_has_a_source_per_number():
    with open(human_file(), "rb") as file:
        human = tomllib.load(file)
    from rhi.master.phenomena import moving_hand  # a protocol of its own, not a sweep

    assert set(human) == {reports.PHENOMENA[name].human for name in NAMES} | {moving_hand.HUMAN_TABLE}
    for table in human.values():
        for reference in table["reference"]:
            assert reference["kind"] in ("boundary", "tested", "marker", "band")
            assert reference["source"] and reference["short"] and reference["says"]
            assert isinstance(reference["checked"], bool)


def test_rows_and_table_by_hand(tmp_path):
    """Two delays, two trials each: means, sample sd and the drift relative to the shortest delay."""
    base = shipped("temporal-window")
    base["experiment"]["decoders"] = ["conv"]
    base["experiment"]["conditions"] = ["left"]
    base["sweep"]["trials"] = 2
    base["sweep"]["points"] = delays(base, 0.0, 0.4)
    path = tmp_path / "tw.toml"
    path.write_text(to_toml(base))
    sweep = sweeps.load(path)
    outcomes = [(-2.0, -0.1, 0.9), (-4.0, -0.3, 1.0), (-1.0, -0.05, 0.2), (-0.5, -0.01, 0.1)]
    records = {t.id: {"status": "ok", "outcome": {"drift_cm": d, "force_n": f, "gamma_final": g}}
               for t, (d, f, g) in zip(sweep.trials, outcomes)}
    found = reports.rows(reports.PHENOMENA["temporal-window"], sweep, records)
    assert [(r["x"], r["n_trials"]) for r in found] == [(0.0, 2), (0.4, 2)]
    assert found[0]["drift_cm_mean"] == -3.0 and found[0]["drift_cm_sd"] == pytest.approx(np.sqrt(2.0))
    assert found[1]["drift_relative"] == pytest.approx(-0.75 / -3.0) and found[0]["drift_relative"] == 1.0
    assert np.isnan(found[0]["drift_half_time_s_mean"])  # not in these outcomes: left blank
    lines = reports.table(reports.PHENOMENA["temporal-window"], found).splitlines()
    assert lines[0].startswith("model,delay_s,decoder,condition,stimulation,n_trials,drift_cm_mean,drift_cm_sd,")
    assert lines[1].split(",")[:8] == ["paper", "0", "conv", "left", "fixed", "2", "-3", "1.41421"]
    header = lines[0].split(",")  # the population's median of two trials is their mean; quartiles by hand
    assert lines[1].split(",")[header.index("drift_cm_median")] == "-3"
    assert lines[1].split(",")[header.index("drift_cm_q25")] == "-3.5"  # -4 + 0.25 * (-2 - -4)
    assert lines[2].endswith(",0.25")
    # a failed trial is left out, and an empty sweep is an error naming the folder
    records[sweep.trials[0].id] = {"status": "failed", "error": "x"}
    assert reports.rows(reports.PHENOMENA["temporal-window"], sweep, records)[0]["n_trials"] == 1
    with pytest.raises(ConfigError, match="no successful trial"):
        reports.report("temporal-window", path, path.parent)


def delays(base: dict, *wanted: float) -> list[dict]:
    """The temporal window's points at these delays."""
    return [p for p in base["sweep"]["points"] if p["stimulations.fixed"]["delay_max"] in wanted]


def quick_copy(name: str, folder: Path) -> Path:
    """The shipped file at quick size: conv only, the [quick] defaults (300 steps, 32 px), two points."""
    base = shipped(name)
    base["experiment"]["decoders"] = ["conv"]
    base["sweep"].update(quick=True, workers=1, trials=1)
    if name == "blocks":  # two points that fit the quick trial of 6 s: blocks of 2 s, and one block
        del base["experiment"]["steps"]  # the file's 120 s would override the quick size
        base["sweep"]["points"] = [{f"stimulations.{s}.blocks": blocks for s in ("sync", "async", "vision")}
                                   for blocks in ([[0, 2], [3, 5]], [])]
    elif "points" in base["sweep"]:
        base["sweep"]["points"] = delays(base, 0.0, 0.4)
    elif name == "vision-only":
        pass  # one point: its x is the stimulation
    elif name in ("time-course", "persistence"):
        base["sweep"]["grid"] = {"experiment.steps": [150, 300]}  # 3 and 6 s
    else:
        base["sweep"]["grid"] = {"conditions.right": [0.05, 0.3]}
    path = folder / f"{name}.toml"
    path.write_text(to_toml(base))
    return path


@pytest.mark.parametrize("name", NAMES)
def test_each_protocol_end_to_end_at_quick_size(name, quick_cache, one_worker, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("RHI_CACHE", str(quick_cache))
    out = tmp_path / "out"
    command = ["phenomenon", name, "--config", str(quick_copy(name, tmp_path)), "--out", str(out), "--model", "paper",
               "--scheduler", one_worker]
    assert main(command) == 0
    stem = FILES[name].removesuffix(".toml")
    assert (out / f"{stem}.png").stat().st_size > 10_000 and (out / "paper" / "sweep.json").exists()
    rows = list(csv.DictReader(open(out / f"{stem}.csv")))
    assert len(rows) == {"temporal-window": 4, "distance": 2, "time-course": 4, "persistence": 2,
                         "vision-only": 6, "blocks": 6}[name]
    for row in rows:
        assert row["n_trials"] == "1" and np.isfinite(float(row["drift_cm_mean"]))
        assert float(row["gamma_final_mean"]) > 0
    if name == "vision-only":  # no touch: the paper's gamma stays at gamma0, its drift at 0
        vision = [r for r in rows if r["stimulation"] == "vision"]
        assert vision and all(float(r["gamma_final_mean"]) == 0.01 for r in vision)
    if name == "time-course":  # the half time is given at the longest trial only
        assert [bool(r["drift_half_time_s_mean"]) for r in rows] == [False, True, False, True]
        assert all(0 < float(r["drift_half_time_s_mean"]) <= 6.0 for r in rows if r["drift_half_time_s_mean"])
    printed = capsys.readouterr().out
    assert f"rhi phenomenon {name}: wrote" in printed
    # run again: nothing reruns (the sweep resumes), the same table
    before = (out / f"{stem}.csv").read_bytes()
    assert main(command) == 0
    assert (out / f"{stem}.csv").read_bytes() == before
    assert "(0 now)" in capsys.readouterr().out


def test_unknown_phenomenon_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["phenomenon", "rubber-duck", "--out", "x"])
    assert exit_.value.code == 2 and "invalid choice" in capsys.readouterr().err
