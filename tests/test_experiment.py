"""`rhi experiment --quick` end to end: the files, their columns, determinism, and bad input."""
import csv
import json
import os
import subprocess
import sys

import pytest

from master.outputs.tables import SUMMARY_COLUMNS


def rhi(*args, cache):
    environment = {**os.environ, "RHI_CACHE": str(cache)}
    return subprocess.run([sys.executable, "-m", "master", *args], capture_output=True, text=True,
                          env=environment, timeout=600)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("decoders")


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory, cache):
    out = tmp_path_factory.mktemp("runs") / "quick"
    result = rhi("experiment", "--quick", "--out", str(out), cache=cache)
    assert result.returncode == 0, result.stderr[-3000:]
    return out


def test_quick_run_writes_the_contract(quick_run):
    assert sorted(p.name for p in quick_run.iterdir()) == ["figures", "run.json", "summary.csv", "trials.csv"]
    with open(quick_run / "summary.csv") as file:
        rows = list(csv.DictReader(file))
    assert list(rows[0]) == SUMMARY_COLUMNS
    assert {(r["decoder"], r["condition"], r["stimulation"]) for r in rows} == {
        (d, c, s) for d in ("conv", "vae") for c in ("left", "center", "right") for s in ("sync", "async")}
    assert all(r["n_trials"] == "1" for r in rows)
    with open(quick_run / "trials.csv") as file:
        reader = csv.DictReader(file)
        header = reader.fieldnames
        count = sum(1 for _ in reader)
    assert header[:7] == ["decoder", "condition", "stimulation", "trial", "seed", "step", "time_s"]
    for column in ("drift_cm", "force_x_n", "gamma", "mu_shoulder_deg", "action_shoulder_deg_s",
                   "action_rate_elbow", "attempted_hand_vx_m_s", "visual_time_s", "tactile_time_s"):
        assert column in header
    assert count == 12 * 301  # 12 trials x (300 steps + the initial row)
    run = json.loads((quick_run / "run.json").read_text())
    assert run["configuration"]["experiment"]["steps"] == 300
    assert len(run["seeds"]["trials"]) == 12 and "torch" in run["versions"]
    figures = sorted(p.name for p in (quick_run / "figures").iterdir())
    for expected in ("a_drift_final.png", "b_drift_sync.png", "c_drift_async.png", "d_force_final.png",
                     "e_force_sync.png", "f_force_async.png", "g_gamma.png", "h_jacobians.png"):
        assert expected in figures
    assert any(name.endswith(".gif") for name in figures)


def test_same_seed_same_bytes(quick_run, cache, tmp_path):
    again = rhi("experiment", "--quick", "--out", str(tmp_path / "again"), cache=cache)
    assert again.returncode == 0, again.stderr[-3000:]
    assert (tmp_path / "again" / "summary.csv").read_bytes() == (quick_run / "summary.csv").read_bytes()
    assert (tmp_path / "again" / "trials.csv").read_bytes() == (quick_run / "trials.csv").read_bytes()


def one_line_error(result, *fragments):
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rhi experiment: error: "), result.stderr
    for fragment in fragments:
        assert fragment in lines[0]


def test_unknown_config_key_is_named_with_a_suggestion(tmp_path, cache):
    config = tmp_path / "bad.toml"
    config.write_text("[brain]\nsigma_p = 2.0\n[experiment]\ntrails = 2\n")
    result = rhi("experiment", "--quick", "--config", str(config), "--out", str(tmp_path / "out"), cache=cache)
    one_line_error(result, "unknown config key brain.sigma_p")
    assert not (tmp_path / "out").exists()


def test_out_of_range_and_foreign_output(tmp_path, cache):
    one_line_error(rhi("experiment", "--quick", "--trials", "0", "--out", str(tmp_path / "o"), cache=cache),
                   "experiment.trials must be at least 1")
    occupied = tmp_path / "occupied"
    occupied.mkdir()
    (occupied / "thesis.tex").write_text("precious")
    one_line_error(rhi("experiment", "--quick", "--out", str(occupied), cache=cache), "--force")
    assert [p.name for p in occupied.iterdir()] == ["thesis.tex"]


def test_unwritable_folder(cache):
    """/proc refuses new folders even to root, so this runs as root too (CI is root)."""
    one_line_error(rhi("experiment", "--quick", "--out", "/proc/rhi-run", cache=cache), "cannot write into /proc")


def test_unwritable_parent_is_refused_without_traces(tmp_path, cache):
    blocker = tmp_path / "file"
    blocker.write_text("")
    one_line_error(rhi("experiment", "--quick", "--out", str(blocker / "run"), cache=cache), "does not exist")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_body_fmu_reproduces_the_native_summary(quick_run, cache, tmp_path):
    """The exported pymunk body, swapped in as an FMU, gives the native run's summary."""
    from master.export.body import build_fmu

    fmu = build_fmu(tmp_path / "Body.fmu", "native")
    result = rhi("experiment", "--quick", "--body", str(fmu), "--out", str(tmp_path / "fmu"), cache=cache)
    assert result.returncode == 0, result.stderr[-3000:]
    assert (tmp_path / "fmu" / "summary.csv").read_bytes() == (quick_run / "summary.csv").read_bytes()
    assert json.loads((tmp_path / "fmu" / "run.json").read_text())["body"] == str(fmu)


def test_a_broken_body_fmu_is_refused_before_any_work(tmp_path, cache):
    fake = tmp_path / "Body.fmu"
    fake.write_text("not a zip")
    one_line_error(rhi("experiment", "--quick", "--body", str(fake), "--out", str(tmp_path / "o"), cache=cache),
                   "Body.fmu cannot be used")
    assert not (tmp_path / "o").exists()
