"""`rhi experiment --quick` end to end: the files, their columns, determinism, the qualitative result, a failing
trial left out, and bad input."""
import csv
import json
import os
import subprocess
import sys
from collections import defaultdict

import numpy as np
import pytest
from docs_tables import names

from rhi.master.outputs.tables import SCHEMA_VERSION, SUMMARY_COLUMNS
from tests.in_process import rhi_in_process


def rhi(*args, cache, one_core=False, **environment):
    """`rhi ARGS` in a child with RHI_CACHE = cache; one_core: pinned to one core (the batches then run one
    after the other, in the command's own process)."""
    environment = {**os.environ, "RHI_CACHE": str(cache), **environment}
    pin = (lambda: os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})) if one_core else None
    return subprocess.run([sys.executable, "-m", "rhi", *args], capture_output=True, text=True,
                          env=environment, timeout=600, preexec_fn=pin)


def refusal(*args, cache):
    """`rhi ARGS` for a run refused before any work: main() in this process (tests/in_process.py), as a
    subprocess would give it, without a second of interpreter start-up each."""
    done = rhi_in_process(list(args), os.getcwd(), {"RHI_CACHE": str(cache)})
    return subprocess.CompletedProcess(["rhi", *args], done.status, done.stdout, done.stderr)


@pytest.fixture(scope="module")
def cache(quick_cache):
    return quick_cache  # the session's --quick decoders (tests/conftest.py): the runs below train nothing


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory, cache):
    out = tmp_path_factory.mktemp("runs") / "quick"
    result = rhi("experiment", "--quick", "--out", str(out), cache=cache)
    assert result.returncode == 0, result.stderr[-3000:]
    return out


def test_quick_run_writes_the_contract(quick_run):
    assert sorted(p.name for p in quick_run.iterdir()) == [".rhi-manifest.json", "figures", "per_step.nc", "run.json", "summary.csv",
                                                         "trials.csv"]
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
                   "action_rate_elbow_deg_s2", "action_accel_x_m_s2", "visual_time_s", "tactile_time_s"):
        assert column in header
    assert count == 12 * 301  # 12 trials x (300 steps + the initial row)
    assert header == names("configuration.md", "trials-columns")  # docs/configuration.md lists a run's columns
    assert list(rows[0]) == names("configuration.md", "summary-columns")
    run = json.loads((quick_run / "run.json").read_text())
    assert run["schema_version"] == SCHEMA_VERSION
    assert run["configuration"]["experiment"]["steps"] == 300
    assert len(run["seeds"]["trials"]) == 12 and "torch" in run["versions"]
    figures = sorted(p.name for p in (quick_run / "figures").iterdir())
    for expected in ("a_drift_final.png", "b_drift_sync.png", "c_drift_async.png", "d_force_final.png",
                     "e_force_sync.png", "f_force_async.png", "g_gamma.png", "h_jacobians.png"):
        assert expected in figures
    assert any(name.endswith(".gif") for name in figures)


def test_same_seed_same_bytes(quick_run, cache, tmp_path):
    """Again, on one core: the decoders' batches one after the other instead of side by side, the same bytes."""
    again = rhi("experiment", "--quick", "--out", str(tmp_path / "again"), cache=cache, one_core=True)
    assert again.returncode == 0, again.stderr[-3000:]
    assert (tmp_path / "again" / "summary.csv").read_bytes() == (quick_run / "summary.csv").read_bytes()
    for name in ("trials.csv", "per_step.nc"):
        assert (tmp_path / "again" / name).read_bytes() == (quick_run / name).read_bytes(), name
    figures = sorted(path.name for path in (quick_run / "figures").iterdir())  # written side by side, then in turn
    assert figures == sorted(path.name for path in (tmp_path / "again" / "figures").iterdir())
    for name in figures:
        assert (tmp_path / "again" / "figures" / name).read_bytes() == (quick_run / "figures" / name).read_bytes()


def one_line_error(result, *fragments):
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rhi experiment: error: "), result.stderr
    for fragment in fragments:
        assert fragment in lines[0]


def test_unknown_config_key_is_named_with_a_suggestion(tmp_path, cache):
    config = tmp_path / "bad.toml"
    config.write_text("[brain]\nsigma_p = 2.0\n[experiment]\ntrails = 2\n")
    result = refusal("experiment", "--quick", "--config", str(config), "--out", str(tmp_path / "out"), cache=cache)
    one_line_error(result, "unknown config key brain.sigma_p")
    assert not (tmp_path / "out").exists()


def test_out_of_range_and_foreign_output(tmp_path, cache):
    one_line_error(refusal("experiment", "--quick", "--trials", "0", "--out", str(tmp_path / "o"), cache=cache),
                   "experiment.trials must be at least 1")
    occupied = tmp_path / "occupied"
    occupied.mkdir()
    (occupied / "thesis.tex").write_text("precious")
    one_line_error(refusal("experiment", "--quick", "--out", str(occupied), cache=cache), "--force")
    assert [p.name for p in occupied.iterdir()] == ["thesis.tex"]


def test_unwritable_folder(cache):
    """/proc refuses new folders even to root, so this runs as root too (CI is root)."""
    one_line_error(refusal("experiment", "--quick", "--out", "/proc/rhi-run", cache=cache), "cannot write into /proc")


def test_unwritable_parent_is_refused_without_traces(tmp_path, cache):
    blocker = tmp_path / "file"
    blocker.write_text("")
    one_line_error(refusal("experiment", "--quick", "--out", str(blocker / "run"), cache=cache), "does not exist")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_body_fmu_reproduces_the_native_summary(quick_run, cache, tmp_path):
    """The exported pymunk body, swapped in as an FMU, gives the native run's summary (its conv decoder's rows: a
    trial's numbers do not depend on the other decoder's trials)."""
    from rhi.master.export.body import build_fmu

    fmu = build_fmu(tmp_path / "Body.fmu", "native")
    (tmp_path / "conv.toml").write_text('[experiment]\ndecoders = ["conv"]\n')
    result = rhi("experiment", "--quick", "--config", str(tmp_path / "conv.toml"), "--body", str(fmu), "--out",
                 str(tmp_path / "fmu"), cache=cache)
    assert result.returncode == 0, result.stderr[-3000:]
    native = [line for line in (quick_run / "summary.csv").read_text().splitlines(keepends=True)
              if not line.startswith("vae,")]
    assert len(native) == 7 and (tmp_path / "fmu" / "summary.csv").read_text() == "".join(native)
    assert json.loads((tmp_path / "fmu" / "run.json").read_text())["body"] == str(fmu)


def test_a_broken_body_fmu_is_refused_before_any_work(tmp_path, cache):
    fake = tmp_path / "Body.fmu"
    fake.write_text("not a zip")
    one_line_error(refusal("experiment", "--quick", "--body", str(fake), "--out", str(tmp_path / "o"), cache=cache),
                   "Body.fmu cannot be used")
    assert not (tmp_path / "o").exists()


def read_trials(folder):
    """trials.csv as {(decoder, condition, stimulation, trial): {column: (steps + 1,) floats}}."""
    columns = defaultdict(lambda: defaultdict(list))
    with open(folder / "trials.csv") as file:
        for row in csv.DictReader(file):
            key = (row["decoder"], row["condition"], row["stimulation"], int(row["trial"]))
            for name, value in row.items():
                if name not in ("decoder", "condition", "stimulation", "trial"):
                    columns[key][name].append(float(value))
    return {key: {name: np.array(values) for name, values in table.items()} for key, table in columns.items()}


def test_the_quick_run_shows_the_illusion(quick_run):
    """The paper's qualitative result (docs/design.md, What the paper found), with the --quick decoders trained by the
    run, 6 s per trial: under synchronous touch the perceived hand drifts toward the rubber hand (Left negative,
    Right positive, Center near 0) and the force points the same way; asynchronous touch attenuates the drift; gamma
    rises from gamma0 under synchronous touch and stays near it under asynchronous touch.
    Measured (conv / vae): sync left -0.18 / -0.18 cm, right +0.30 / +0.24 cm, center +0.02 / -0.01 cm; async
    8-10 % of sync; gamma 0.115-0.128 sync, 0.010-0.011 async."""
    with open(quick_run / "summary.csv") as file:
        cell = {(r["decoder"], r["condition"], r["stimulation"]): {k: float(v) for k, v in r.items()
                                                                   if k.endswith(("mean", "sd"))}
                for r in csv.DictReader(file)}
    for decoder in ("conv", "vae"):
        drift = {(c, s): cell[(decoder, c, s)]["drift_cm_mean"] for c in ("left", "center", "right")
                 for s in ("sync", "async")}
        force = {(c, s): cell[(decoder, c, s)]["force_n_mean"] for c in ("left", "right") for s in ("sync", "async")}
        gamma = {s: [cell[(decoder, c, s)]["gamma_final_mean"] for c in ("left", "center", "right")]
                 for s in ("sync", "async")}
        assert drift[("left", "sync")] < 0 < drift[("right", "sync")], (decoder, drift)
        assert force[("left", "sync")] < 0 < force[("right", "sync")], (decoder, force)
        side = min(abs(drift[("left", "sync")]), abs(drift[("right", "sync")]))
        assert side > 0.05 and abs(drift[("center", "sync")]) < 0.25 * side, (decoder, drift)
        for condition in ("left", "right"):
            assert abs(drift[(condition, "async")]) < 0.25 * abs(drift[(condition, "sync")]), (decoder, drift)
        assert min(gamma["sync"]) > 0.05 and max(gamma["async"]) < 0.5 * min(gamma["sync"]), (decoder, gamma)

    for (decoder, condition, stimulation, _), trial in read_trials(quick_run).items():
        assert trial["drift_cm"][0] == 0 and trial["gamma"][0] == 0.01  # no illusion before the first touch
        if stimulation == "sync":  # gamma climbs touch by touch: the touches felt at about 2.05 and 4.05 s
            after = [trial["gamma"][np.isclose(trial["time_s"], t)][0] for t in (2.5, 4.5)]
            assert 0.01 < after[0] < after[1], (decoder, condition, after)


# A body whose second instance in the process (one FMU instance per trial) puts NaN into force_x from t = 0.1 s on.
COUNTED_PLANTS = '''
import os

import numpy as np

from rhi.components.body.plant import ArmPlant


class NanSecondInstance(ArmPlant):
    """The second instance made in a process outputs NaN force_x from t = 0.1 s on (count in $RHI_TEST_COUNT)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.doomed = False
        if os.environ.get("RHI_TEST_COUNT"):  # not while the FMU is built
            counter = os.path.join(os.environ["RHI_TEST_COUNT"], "instances")
            made = int(open(counter).read()) if os.path.exists(counter) else 0
            with open(counter, "w") as file:
                file.write(str(made + 1))
            self.doomed = made == 1

    def step(self, t, h):
        super().step(t, h)
        if self.doomed and t >= 0.1 - 1e-9:
            self.values["force_x"] = np.full(self.batch_size, np.nan)
'''


def test_a_failing_trial_is_left_out_and_the_rest_are_written(quick_run, cache, tmp_path):
    """Through the command line: an FMU body that emits NaN in one trial (the conv batch's second, conv/left/sync
    trial 1). The run exits 1 naming it, run.json lists it under failed_trials, its cell counts one trial less, and
    every other trial is written with the numbers it has without the failure (trial 0 of each cell: those of the
    native quick run, whose first 21 rows this run repeats)."""
    from rhi.master.export.body import build_fmu

    plants = tmp_path / "rhi_test_counted_plants.py"
    plants.write_text(COUNTED_PLANTS)
    fmu = build_fmu(tmp_path / "Nan.fmu", component="rhi_test_counted_plants:NanSecondInstance",
                    model_name="NanSecondInstance", extra_files=[plants])
    (tmp_path / "count").mkdir()
    out = tmp_path / "out"
    # One core: the plant counts the instances made in one process, so the batches run one after the other there.
    result = rhi("experiment", "--quick", "--trials", "2", "--steps", "20", "--body", str(fmu), "--out", str(out),
                 cache=cache, one_core=True, RHI_TEST_COUNT=str(tmp_path / "count"))
    assert result.returncode == 1, result.stderr[-3000:]
    assert (tmp_path / "count" / "instances").read_text() == str(12 + 11 + 12)  # conv, conv again without it, vae
    named = [line for line in result.stderr.splitlines() if line.startswith("rhi experiment: trial failed")]
    assert len(named) == 1 and "conv/left/sync trial 1" in named[0] and "force_x is nan" in named[0], result.stderr
    assert "Traceback" not in result.stderr

    failed = json.loads((out / "run.json").read_text())["failed_trials"]
    assert [(f["decoder"], f["condition"], f["stimulation"], f["index"]) for f in failed] == [("conv", "left", "sync", 1)]
    assert "force_x is nan" in failed[0]["error"] and "t = 0.12 s" in failed[0]["error"]
    with open(out / "summary.csv") as file:
        counts = {(r["decoder"], r["condition"], r["stimulation"]): int(r["n_trials"]) for r in csv.DictReader(file)}
    assert len(counts) == 12 and counts.pop(("conv", "left", "sync")) == 1 and set(counts.values()) == {2}

    written, native = read_trials(out), read_trials(quick_run)
    assert len(written) == 23 and ("conv", "left", "sync", 1) not in written
    for key, trial in written.items():
        assert len(trial["step"]) == 21 and np.isfinite(trial["force_x_n"]).all(), key
        if key[3] == 0:  # rerun in a smaller batch: other float32 sums, as tests/test_batching.py derives
            for name, column in trial.items():
                np.testing.assert_allclose(column, native[key][name][:21], rtol=1e-5, atol=1e-9, err_msg=f"{key} {name}")
    assert sorted(p.name for p in out.iterdir()) == [".rhi-manifest.json", "figures", "per_step.nc", "run.json", "summary.csv",
                                                         "trials.csv"]
