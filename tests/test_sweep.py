"""Sweeps on a real Dask cluster against the local pool: the same trials, failing points, a different sweep, the
experiment's own lockstep chunks.

The trials run tests/sweep_tasks.py stand-ins, whose exact results the tests compute themselves.
"""
import csv
import json
import subprocess

import numpy as np
import pytest

from rhi.master.sweeps import plan as sweeps
from rhi.master import config as configuration
from rhi.master.commands.cli import main
from rhi.master.commands.sweep import run as run_sweep
from tests.sweep_files import ENV, args, dask_cluster_at, batched_file, command, expected, lockstep_truth, records, single_core, sweep_file

@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    """A real `dask scheduler` and two `dask worker` processes on 127.0.0.1, on ports the OS picks."""
    with dask_cluster_at(tmp_path_factory.mktemp("cluster"), workers=2) as address:
        yield address


def test_local_pool_and_dask_cluster_give_the_same_trials(dask_cluster, tmp_path, capsys):
    from rhi.master.runtime.logs import configured
    from rhi.master.sweeps.runner import WORKER_SETTINGS

    path = sweep_file(tmp_path / "s.toml", grid={"stimulations.sync.delay_max": [0.1, 0.6],
                                                 "conditions.left": [-0.15, -0.3]})
    sweep = sweeps.load(path)

    def notes():
        return [line for line in capsys.readouterr().err.splitlines() if "note:" in line]

    assert run_sweep(args(path, tmp_path / "local")) == 0
    assert notes() == []  # the local pool's workers have WORKER_SETTINGS
    with configured(0):  # the note logged on stderr, as the command line sets it up
        assert run_sweep(args(path, tmp_path / "cluster", scheduler=dask_cluster)) == 0
    # the fixture's workers run with Dask's defaults: one note names every setting they lack
    assert notes() == ["rhi sweep: note: 2 of 2 Dask workers lack the settings for long CPU-bound tasks "
                       f"({', '.join(sorted(WORKER_SETTINGS))}), which slows the trials; docs/sweeps.md "
                       "shows how to start them"]
    local, cluster, truth = records(tmp_path / "local"), records(tmp_path / "cluster"), expected(sweep)
    assert set(local) == set(cluster) == set(truth) and len(truth) == 16
    for trial in sweep.trials:
        assert local[trial.id]["outcome"] == cluster[trial.id]["outcome"] == truth[trial.id]
        assert local[trial.id]["seed"] == trial.seed and local[trial.id]["status"] == "ok"
    # summary.csv: mean and sample sd per point and cell, against numpy on the true outcomes
    rows = list(csv.DictReader(open(tmp_path / "cluster" / "summary.csv")))
    assert len(rows) == 4 * 2
    for row in rows:
        members = [truth[t.id] for t in sweep.trials
                   if t.point == int(row["point"]) and t.condition == row["condition"]]
        drift = np.array([m["drift_cm"] for m in members])
        assert int(row["n_trials"]) == 2 and int(row["n_failed"]) == 0
        assert float(row["drift_cm_mean"]) == pytest.approx(drift.mean(), rel=1e-5)
        assert float(row["drift_cm_sd"]) == pytest.approx(abs(drift[0] - drift[1]) / np.sqrt(2), rel=1e-5)
    assert float(rows[0]["conditions.left"]) == -0.15 and float(rows[2]["conditions.left"]) == -0.3
    figures = sorted(p.name for p in (tmp_path / "cluster" / "figures").glob("*.png"))
    assert figures == ["conditions.left.png", "stimulations.sync.delay_max.png"]


def test_failing_point_is_listed_and_the_rest_complete(dask_cluster, tmp_path):
    # faulty_outcome fails a rubber hand right of the real one (offset > 0) when the trial runs
    path = sweep_file(tmp_path / "s.toml", grid={"conditions.left": [-0.15, 0.3]}, conditions=("left", "center"),
                      task="faulty_outcome")
    result = subprocess.run(command("--config", path, "--scheduler", dask_cluster, "--out", tmp_path / "out"),
                            env=ENV, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    listed = [line for line in result.stderr.splitlines() if line.startswith("rhi sweep: failed:")]
    assert len(listed) == 2
    assert all("point 1 (conditions.left=0.3) conv/left/sync" in line and "a fault on demand" in line for line in listed)
    done = records(tmp_path / "out")
    assert sorted(r["status"] for r in done.values()) == ["failed"] * 2 + ["ok"] * 6
    rows = {(r["point"], r["condition"]): r for r in csv.DictReader(open(tmp_path / "out" / "summary.csv"))}
    assert (rows[("1", "left")]["n_trials"], rows[("1", "left")]["n_failed"]) == ("0", "2")
    assert rows[("1", "left")]["drift_cm_mean"] == ""
    assert (rows[("1", "center")]["n_trials"], rows[("1", "center")]["n_failed"]) == ("2", "0")


def test_different_sweep_is_refused_and_force_keeps_shared_trials(dask_cluster, tmp_path, capsys):
    out = tmp_path / "out"
    first = sweep_file(tmp_path / "a.toml", grid={"stimulations.sync.delay_max": [0.1, 0.6]}, trials=1)
    assert main(["sweep", "--config", str(first), "--scheduler", dask_cluster, "--out", str(out)]) == 0
    assert main(["sweep", "--config", str(first), "--out", str(out)]) == 0  # same sweep: nothing left to do
    assert "4 of 4 trials done (0 now)" in capsys.readouterr().out
    second = sweep_file(tmp_path / "b.toml", grid={"stimulations.sync.delay_max": [0.1, 0.9]}, trials=1)
    assert main(["sweep", "--config", str(second), "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("rhi sweep: error: output folder") and "holds a different sweep" in error
    assert "\n" not in error
    kept = {t.id for t in sweeps.load(first).trials if t.point == 0}
    stamps = {key: (out / "trials" / f"{key}.json").stat().st_mtime_ns for key in kept}
    assert main(["sweep", "--config", str(second), "--scheduler", dask_cluster, "--out", str(out), "--force"]) == 0
    assert set(records(out)) == {t.id for t in sweeps.load(second).trials}
    assert {key: (out / "trials" / f"{key}.json").stat().st_mtime_ns for key in kept} == stamps
    assert "4 of 4 trials done (2 now)" in capsys.readouterr().out


def test_tiny_real_sweep_matches_the_trial_run_here(dask_cluster, tmp_path, monkeypatch):
    """rhi.master.tasks.illusion.trial_outcome through the cluster: the same numbers as one call in this process."""
    from rhi.master.decoders.cache import ensure_checkpoints
    from rhi.master.tasks.illusion import trial_outcome

    monkeypatch.setenv("RHI_CACHE", str(tmp_path / "cache"))
    (tmp_path / "base.toml").write_text('[experiment]\ndecoders = ["conv"]\n[train]\nsamples = 200\nepochs = 2\n')
    paths, _ = ensure_checkpoints(configuration.load(tmp_path / "base.toml", quick=True), progress=False)
    checkpoint = paths["conv"]  # named in the sweep file: the workers do not share this process's cache
    # 22 steps of 0.1 s hold the first touch (t = 2 s); fixed delays: sync 0.05 s, async 0.9 s
    path = tmp_path / "s.toml"
    path.write_text(f"""[experiment]
decoders = ["conv"]
conditions = ["left"]
stimulations = ["sync"]
steps = 22
step_size = 0.1
[body]
substeps = 40
[train]
samples = 200
epochs = 2
[decoder]
conv_checkpoint = "{checkpoint}"
[sweep]
quick = true
[[sweep.points]]
"stimulations.sync" = {{delay_min = 0.05, delay_max = 0.05}}
[[sweep.points]]
"stimulations.sync" = {{delay_min = 0.9, delay_max = 0.9}}
""")
    sweep = sweeps.load(path)
    assert run_sweep(args(path, tmp_path / "out", scheduler=dask_cluster)) == 0
    done = records(tmp_path / "out")
    synchronous, asynchronous = (done[t.id]["outcome"] for t in sweep.trials)
    here = single_core(trial_outcome, sweep.configs[0], "conv", "left", "sync", 0)
    assert synchronous == pytest.approx(here, rel=1e-9, abs=1e-12, nan_ok=True)  # no half-decay: touch goes on
    # by hand: the touch pair seen at t = 2.1 s (t_v - t_t = -0.05 s) updates gamma0 = 0.01 with
    # p1 = N(0.05; 0, 0.2) against p2 = 0.5; at t = 2.2 s it decays by exp(-(2.2 - 2.05)^2 dt / 80)
    p1 = np.exp(-0.5 * (0.05 / 0.2) ** 2) / (0.2 * np.sqrt(2 * np.pi))
    updated = p1 * 0.01 / (p1 * 0.01 + 0.5 * 0.99)
    assert synchronous["gamma_final"] == pytest.approx(updated * np.exp(-0.15 ** 2 * 0.1 / 80), rel=1e-9)
    assert asynchronous["gamma_final"] == 0.01  # p1 = N(0.9; 0, 0.2) << p2: clamped at gamma0


@pytest.fixture(scope="module")
def quick_decoders(quick_cache):
    """The session's --quick conv and vae checkpoints, named in the sweep files (remote workers share no cache)."""
    return {kind: str(next(quick_cache.glob(f"{kind}-*.pt"))) for kind in ("conv", "vae")}


def test_batched_sweep_is_run_batch_on_the_local_pool_and_the_cluster(dask_cluster, quick_decoders, tmp_path):
    path = batched_file(tmp_path / "s.toml", quick_decoders, grid={"stimulations.sync.delay_max": [0.1, 0.6]},
                        batch=5)
    sweep = sweeps.load(path)
    assert [len(chunk) for chunk in sweep.chunks] == [4, 4] * 4
    assert run_sweep(args(path, tmp_path / "local")) == 0
    assert run_sweep(args(path, tmp_path / "cluster", scheduler=dask_cluster)) == 0
    local, cluster, truth = records(tmp_path / "local"), records(tmp_path / "cluster"), lockstep_truth(sweep)
    assert set(local) == set(cluster) == set(truth) and len(truth) == 32
    for trial in sweep.trials:
        outcome = local[trial.id]["outcome"]
        assert outcome == cluster[trial.id]["outcome"]  # bitwise, every key
        assert {key: outcome[key] for key in truth[trial.id]} == truth[trial.id]  # bitwise
        assert outcome["seed"] == trial.seed and local[trial.id]["batch"] == 4
    manifest = json.loads((tmp_path / "cluster" / "sweep.json").read_text())
    assert (manifest["trials_planned"], manifest["tasks_planned"], manifest["lockstep_batches"]) == (32, 8, True)
    gammas = [local[t.id]["outcome"]["gamma_final"] for t in sweep.trials]
    assert max(gammas) > 0.02 and min(gammas) == 0.01  # sync touches raised gamma; async left it at gamma0


