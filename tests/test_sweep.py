"""Sweeps: grid expansion, a real Dask cluster against the local pool, kill and resume, failing points.

The trials run tests/sweep_tasks.py stand-ins, whose exact results the tests compute themselves.
"""
import argparse
import csv
import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from master.sweeps import plan as sweeps
from master.cosim import ConfigError
from master.experiment import config as configuration
from master.experiment import trial_seed
from master.commands.cli import main
from master.commands.sweep import run_sweep
from tests.sweep_tasks import fake_outcome

REPO = Path(__file__).resolve().parents[1]
DASK = Path(sys.executable).with_name("dask")
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}


def sweep_file(path, grid=None, points=None, task="fake_outcome", trials=2, conditions=("left", "right"),
               workers=2, extra=""):
    lines = ["[experiment]", 'decoders = ["conv"]', f"conditions = {json.dumps(list(conditions))}",
             'stimulations = ["sync"]', extra, "[sweep]", f"trials = {trials}", f"workers = {workers}",
             f'task = "tests.sweep_tasks:{task}"']
    if grid is not None:
        lines += ["[sweep.grid]", *(f'"{key}" = {json.dumps(values)}' for key, values in grid.items())]
    for point in points or []:
        lines += ["[[sweep.points]]", *(f'"{key}" = {json.dumps(value)}' for key, value in point.items())]
    path.write_text("\n".join(lines) + "\n")
    return path


def args(config, out, scheduler=None, force=False):
    return argparse.Namespace(config=str(config), out=str(out), scheduler=scheduler, force=force, debug=False)


def records(out):
    return {path.stem: json.loads(path.read_text()) for path in (Path(out) / "trials").glob("*.json")}


def expected(sweep):
    """Every trial's outcome, computed here without Dask: the independent truth."""
    return {t.id: fake_outcome(sweep.configs[t.point], t.decoder, t.condition, t.stimulation, t.index)
            for t in sweep.trials}


def command(*arguments):
    return [sys.executable, "-m", "master", "sweep", *map(str, arguments)]


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    """A real `dask scheduler` and two `dask worker` processes on 127.0.0.1, on ports the OS picks."""
    from dask.distributed import Client

    folder = tmp_path_factory.mktemp("cluster")
    log = open(folder / "cluster.log", "w")
    started = []

    def start(*arguments, core=None):
        pin = None if core is None else (lambda: os.sched_setaffinity(0, {core}))
        started.append(subprocess.Popen([str(DASK), *arguments], stdout=log, stderr=subprocess.STDOUT, env=ENV,
                                        cwd=folder, start_new_session=True, preexec_fn=pin))

    try:
        start("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
              "--scheduler-file", str(folder / "scheduler.json"))
        deadline = time.monotonic() + 60
        while not (folder / "scheduler.json").exists():
            assert time.monotonic() < deadline and started[0].poll() is None, "the dask scheduler did not start"
            time.sleep(0.1)
        address = json.loads((folder / "scheduler.json").read_text())["address"]
        # one core each, as sweep workers are meant to be: the decoder sizes torch's threads from the
        # process's cores, and two-thread processes on two busy cores run small convolutions ~30x slower
        cores = sorted(os.sched_getaffinity(0))
        for number, name in enumerate(("w0", "w1")):
            start("worker", address, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny", "--no-dashboard",
                  "--name", name, "--local-directory", str(folder), "--death-timeout", "60",
                  core=cores[number % len(cores)])
        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=90)
        yield address
    finally:
        for group in (started[1:], started[:1]):  # workers first: they would wait for a lost scheduler
            for process in group:
                process.terminate()
            for process in group:
                try:
                    process.wait(timeout=10)
                except subprocess.TimeoutExpired:  # its own session: the group holds only what it started
                    os.killpg(process.pid, signal.SIGKILL)
                    process.wait()
        log.close()


def test_grid_points_ids_and_validation(tmp_path):
    path = sweep_file(tmp_path / "s.toml", grid={"stimulations.sync.delay_max": [0.1, 0.5],
                                                 "conditions.left": [-0.15, -0.3, -0.4]})
    sweep = sweeps.load(path)
    # the last key varies fastest, as in the file
    assert [tuple(p.values()) for p in sweep.points] == [
        (0.1, -0.15), (0.1, -0.3), (0.1, -0.4), (0.5, -0.15), (0.5, -0.3), (0.5, -0.4)]
    assert sweep.keys == ["stimulations.sync.delay_max", "conditions.left"]
    assert sweep.configs[4]["stimulations"]["sync"]["delay_max"] == 0.5
    assert sweep.configs[4]["conditions"]["left"] == -0.3
    assert sweep.configs[4]["experiment"]["trials"] == 2
    assert len(sweep.trials) == 6 * 2 * 2  # points x conditions x trials (one decoder, one stimulation)
    first = sweep.trials[0]
    assert (first.decoder, first.condition, first.stimulation, first.index) == ("conv", "left", "sync", 0)
    assert first.seed == trial_seed(0, "left", "sync", 0)
    assert len({t.id for t in sweep.trials}) == len(sweep.trials)
    assert [t.id for t in sweeps.load(path).trials] == [t.id for t in sweep.trials]  # stable
    # a point shared with another sweep is the same trial there (what --force keeps)
    other = sweeps.load(sweep_file(tmp_path / "o.toml", points=[{"stimulations.sync.delay_max": 0.5,
                                                                 "conditions.left": -0.3}]))
    assert {t.id for t in other.trials} <= {t.id for t in sweep.trials}
    reseeded = sweeps.load(sweep_file(tmp_path / "r.toml", points=[{"experiment.seed": 7}]))
    assert reseeded.trials[0].seed == trial_seed(7, "left", "sync", 0) != first.seed

    def error(**kwargs):
        with pytest.raises(ConfigError) as caught:
            sweeps.load(sweep_file(tmp_path / "bad.toml", **kwargs))
        return str(caught.value)

    assert "did you mean stimulations.sync.delay_max?" in error(grid={"stimulations.sync.dely_max": [1.0]})
    assert "did you mean decoder.visual_variance?" in error(grid={"decoder.visual_varience": [1.0]})
    assert error(grid={"decoder.visual_variance": [1.0, -2.0]}) == (
        "sweep point 1 (decoder.visual_variance=-2.0): decoder.visual_variance must be positive, got -2.0")
    assert "non-empty list" in error(grid={"conditions.left": []})
    assert "points 0 and 1 are the same" in error(points=[{"conditions.left": -0.2}, {"conditions.left": -0.2}])
    assert "cannot be imported" in error(task="no_such_task")
    (tmp_path / "typo.toml").write_text("[sweep]\ntrails = 3\n")
    with pytest.raises(ConfigError, match=r"unknown sweep key sweep.trails \(did you mean sweep.trials\?\)"):
        sweeps.load(tmp_path / "typo.toml")


def test_local_pool_and_dask_cluster_give_the_same_trials(dask_cluster, tmp_path, capsys):
    from master.sweeps.runner import WORKER_SETTINGS

    path = sweep_file(tmp_path / "s.toml", grid={"stimulations.sync.delay_max": [0.1, 0.6],
                                                 "conditions.left": [-0.15, -0.3]})
    sweep = sweeps.load(path)

    def notes():
        return [line for line in capsys.readouterr().err.splitlines() if "note:" in line]

    assert run_sweep(args(path, tmp_path / "local")) == 0
    assert notes() == []  # the local pool's workers have WORKER_SETTINGS
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


def test_killed_sweep_resumes_and_runs_each_trial_once(tmp_path):
    path = sweep_file(tmp_path / "s.toml", task="slow_outcome", trials=3,
                      grid={"stimulations.sync.delay_max": [0.1, 0.6]})
    sweep, out = sweeps.load(path), tmp_path / "out"
    process = subprocess.Popen(command("--config", path, "--out", out), env=ENV, cwd=tmp_path,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while len(list((out / "trials").glob("*.json"))) < 3:
            assert time.monotonic() < deadline and process.poll() is None, "the sweep did not start"
            time.sleep(0.05)
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=10)
        deadline = time.monotonic() + 20  # its worker processes notice and go too
        while True:
            try:
                os.killpg(process.pid, 0)
            except ProcessLookupError:
                break
            assert time.monotonic() < deadline, "worker processes outlived the killed sweep"
            time.sleep(0.2)
    finally:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    before = records(out)
    assert 3 <= len(before) < len(sweep.trials) == 12
    stamps = {path: path.stat().st_mtime_ns for path in (out / "trials").glob("*.json")}
    rerun = subprocess.run(command("--config", path, "--out", out), env=ENV, cwd=tmp_path,
                           capture_output=True, text=True, timeout=120)
    assert rerun.returncode == 0, rerun.stderr
    assert f"12 of 12 trials done ({12 - len(before)} now)" in rerun.stdout
    assert all(path.stat().st_mtime_ns == stamp for path, stamp in stamps.items())  # not run again
    after, truth = records(out), expected(sweep)
    assert set(after) == set(truth)
    assert {key: record["outcome"] for key, record in after.items()} == truth
    index = list(csv.DictReader(open(out / "index.csv")))
    assert sorted(row["id"] for row in index) == sorted(truth)  # each trial exactly once
    # the manifest lists what rhi wrote, each file's sha256 as hashlib computes it: at least the rerun's
    # records (those of the killed run only if it listed them before it died) and the tables
    listed = json.loads((out / ".rhi-manifest.json").read_text())["files"]
    rerun_records = {f"trials/{p.name}" for p in (out / "trials").glob("*.json") if p not in stamps}
    assert rerun_records | {"sweep.json", "index.csv", "summary.csv"} <= set(listed)
    assert all(hashlib.sha256((out / name).read_bytes()).hexdigest() == entry["sha256"] and
               (out / name).stat().st_size == entry["bytes"] for name, entry in listed.items())


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


def single_core(function, *arguments):
    """``function(*arguments)`` in this process on one core, like a sweep worker; then as before."""
    import torch

    cores, threads = os.sched_getaffinity(0), torch.get_num_threads()
    os.sched_setaffinity(0, {min(cores)})
    try:
        return function(*arguments)
    finally:
        os.sched_setaffinity(0, cores)
        torch.set_num_threads(threads)


def test_tiny_real_sweep_matches_the_trial_run_here(dask_cluster, tmp_path, monkeypatch):
    """master.experiment.trial_outcome through the cluster: the same numbers as one call in this process."""
    from master.experiment.decoders import ensure_checkpoints
    from master.experiment import trial_outcome

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


# -- the experiment's own trial function: lockstep chunks ------------------------------------------
def batched_file(path, checkpoints, grid=None, batch=None, workers=2, conditions=("left", "right"), trials=2):
    """A sweep of the default task at quick size: 30 steps of 0.1 s (touches at 2 s), the named decoders."""
    lines = ["[experiment]", 'decoders = ["conv", "vae"]', f"conditions = {json.dumps(list(conditions))}",
             "steps = 30", "step_size = 0.1", "[body]", "substeps = 40", "[decoder]",
             *(f'{kind}_checkpoint = "{checkpoint}"' for kind, checkpoint in checkpoints.items()),
             "[sweep]", "quick = true", f"trials = {trials}", f"workers = {workers}",
             *([f"batch = {batch}"] if batch else [])]
    if grid:
        lines += ["[sweep.grid]", *(f'"{key}" = {json.dumps(values)}' for key, values in grid.items())]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def quick_decoders(quick_cache):
    """The session's --quick conv and vae checkpoints, named in the sweep files (remote workers share no cache)."""
    return {kind: str(next(quick_cache.glob(f"{kind}-*.pt"))) for kind in ("conv", "vae")}


def lockstep_truth(sweep) -> dict:
    """Every ok trial's drift, force and gamma from run_batch on its chunk's trials, here, on one core."""
    from master.experiment import make_trial, measures, run_batch
    from master.experiment.decoders import checkpoint_path, decoder_component
    from master.experiment.measures import end_of_trial

    truth = {}
    for chunk in sweep.chunks:
        members = [sweep.trials[position] for position in chunk]
        config, kind = sweep.configs[members[0].point], members[0].decoder
        trials = [make_trial(config, t.decoder, t.condition, t.stimulation, t.index) for t in members]
        result = single_core(run_batch, decoder_component(kind, checkpoint_path(kind, config), config), trials,
                             config)
        final = end_of_trial(result.times, measures(result))
        for column, trial in enumerate(members):
            truth[trial.id] = {"drift_cm": float(final["drift_cm"][column]),
                               "force_n": float(final["force_x_n"][column]),
                               "gamma_final": float(final["gamma"][column])}
    return truth


def test_chunks_are_fixed_by_the_file_alone(tmp_path):
    """Per point and decoder, consecutive near-equal chunks of at most sweep.batch; ids name the chunk."""
    checkpoints = {"conv": "unused.pt", "vae": "unused.pt"}  # loading a plan opens no checkpoint
    path = batched_file(tmp_path / "s.toml", checkpoints, grid={"conditions.left": [-0.15, -0.3]}, batch=3,
                        trials=2)
    sweep = sweeps.load(path)
    assert sweep.batched and len(sweep.trials) == 2 * 2 * 2 * 2 * 2  # points x decoders x conditions x stims x trials
    # 8 trials per point and decoder, at most 3 a chunk: 3 chunks of 3, 3, 2, in the protocol's order
    assert [len(chunk) for chunk in sweep.chunks] == [3, 3, 2] * 4
    assert [position for chunk in sweep.chunks for position in chunk] == list(range(len(sweep.trials)))
    for chunk in sweep.chunks:
        assert len({(sweep.trials[p].point, sweep.trials[p].decoder) for p in chunk}) == 1
    again = sweeps.load(path)
    assert again.chunks == sweep.chunks and [t.id for t in again.trials] == [t.id for t in sweep.trials]
    # another batch size: other chunks, so other ids (their numbers may differ) and another sweep
    whole = sweeps.load(batched_file(tmp_path / "w.toml", checkpoints, grid={"conditions.left": [-0.15, -0.3]},
                                     trials=2))
    assert [len(chunk) for chunk in whole.chunks] == [8] * 4  # default: all of a point's decoder
    assert not {t.id for t in whole.trials} & {t.id for t in sweep.trials}
    assert whole.fingerprint != sweep.fingerprint
    # the number of workers plans nothing
    more = sweeps.load(batched_file(tmp_path / "m.toml", checkpoints, grid={"conditions.left": [-0.15, -0.3]},
                                    batch=3, workers=1))
    assert more.chunks == sweep.chunks and [t.id for t in more.trials] == [t.id for t in sweep.trials]
    # a widened grid keeps the chunks, and so the ids, of the points it shares
    wider = sweeps.load(batched_file(tmp_path / "g.toml", checkpoints,
                                     grid={"conditions.left": [-0.15, -0.3, -0.45]}, batch=3))
    assert {t.id for t in sweep.trials} < {t.id for t in wider.trials}
    # another task runs trials one by one: chunks of one; sweep.batch is refused for it
    single = sweeps.load(sweep_file(tmp_path / "f.toml", trials=3))
    assert not single.batched and single.chunks == [[n] for n in range(len(single.trials))]
    bad = sweep_file(tmp_path / "b.toml")
    bad.write_text(bad.read_text() + "batch = 2\n")  # into its [sweep] table
    with pytest.raises(ConfigError, match=r"sweep.batch applies to the default task .* once per trial"):
        sweeps.load(bad)


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


def test_killed_batched_sweep_resumes_bitwise(quick_decoders, tmp_path):
    """Killed between chunks, then a record of a finished chunk lost too: the rerun runs each unfinished
    chunk whole and writes only the missing records, bitwise those of an uninterrupted sweep."""
    path = batched_file(tmp_path / "s.toml", quick_decoders, batch=4, workers=1)
    sweep, out = sweeps.load(path), tmp_path / "out"
    assert [len(chunk) for chunk in sweep.chunks] == [4] * 4
    assert run_sweep(args(path, tmp_path / "whole")) == 0
    whole = records(tmp_path / "whole")
    process = subprocess.Popen(command("--config", path, "--out", out), env=ENV, cwd=tmp_path,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while len(list((out / "trials").glob("*.json"))) < 4:  # the first chunk
            assert time.monotonic() < deadline and process.poll() is None, "the sweep did not start"
            time.sleep(0.02)
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=10)
    before = records(out)
    assert 4 <= len(before) < 16
    first = [sweep.trials[p].id for p in sweep.chunks[0]]
    assert set(first) <= set(before)
    (out / "trials" / f"{first[1]}.json").unlink()  # a finished chunk with a record lost
    stamps = {path: path.stat().st_mtime_ns for path in (out / "trials").glob("*.json")}
    rerun = subprocess.run(command("--config", path, "--out", out), env=ENV, cwd=tmp_path,
                           capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert f"16 of 16 trials done ({16 - len(before) + 1} now)" in rerun.stdout
    assert all(path.stat().st_mtime_ns == stamp for path, stamp in stamps.items())  # kept as they were
    after = records(out)
    assert set(after) == set(whole)
    assert {key: r["outcome"] for key, r in after.items()} == {key: r["outcome"] for key, r in whole.items()}
    index = list(csv.DictReader(open(out / "index.csv")))
    assert sorted(row["id"] for row in index) == sorted(whole)  # each trial exactly once


def test_a_failing_trial_costs_its_chunk_only_itself(quick_decoders, monkeypatch):
    """batch_outcomes: a trial a component blames is recorded alone and the rest rerun without it; a
    failure that blames no trial (a rubber hand out of reach) reruns each trial alone. Against run_batch."""
    from master.cosim import SimulationError
    from master.experiment import measures, plan, run_batch
    from master.experiment import runner
    from master.experiment.decoders import decoder_component
    from master.experiment.measures import end_of_trial

    config = configuration.load(quick=True, overrides={
        "experiment.decoders": ["conv"], "experiment.conditions": ["left", "right"], "experiment.trials": 2,
        "experiment.steps": 30, "experiment.step_size": 0.1, "body.substeps": 40,
        "decoder.conv_checkpoint": quick_decoders["conv"]})
    trials = plan(config)  # left sync 0, 1, left async 0, 1, right ...: 8

    def final(batch):
        result = run_batch(decoder_component("conv", quick_decoders["conv"], config), batch, config)
        values = end_of_trial(result.times, measures(result))
        return {t: (float(values["drift_cm"][c]), float(values["gamma"][c])) for c, t in enumerate(batch)}

    calls, blamed = [], trials[2]

    def blaming(decoder, batch, given):
        calls.append(len(batch))
        if blamed in batch:
            raise SimulationError("body", 0.4, "NaN in this trial", trials=(batch.index(blamed),))
        return run_batch(decoder, batch, given)

    monkeypatch.setattr(runner, "run_batch", blaming)
    got = single_core(runner.batch_outcomes, config, "conv", trials)
    assert calls == [8, 7]
    assert got[2] == {"status": "failed", "traceback": "",
                      "error": "SimulationError: body failed the step at t = 0.4 s (error): NaN in this trial"}
    rest = [t for t in trials if t is not blamed]
    truth = single_core(final, rest)
    assert {t: (r["outcome"]["drift_cm"], r["outcome"]["gamma_final"]) for t, r in zip(trials, got)
            if t is not blamed} == truth
    monkeypatch.undo()

    far = configuration.merge(config, {"conditions": {"left": 1.0}})  # out of reach: the whole batch fails
    trials = plan(far)
    got = single_core(runner.batch_outcomes, far, "conv", trials)
    assert all(r["status"] == "failed" and "out of reach" in r["error"] for r in got[:4])
    alone = {t: single_core(final, [t])[t] for t in trials[4:]}  # the others, each a batch of one
    assert {t: (r["outcome"]["drift_cm"], r["outcome"]["gamma_final"]) for t, r in zip(trials[4:], got[4:])} == alone
    assert single_core(runner.trial_outcome, far, "conv", "right", "sync", 1)["gamma_final"] == alone[trials[5]][1]
    with pytest.raises(RuntimeError, match="ComponentError: .* out of reach"):
        runner.trial_outcome(far, "conv", "left", "sync", 0)


def test_tasks_keep_large_temporaries_on_the_heap(tmp_path):
    """Under Dask's nanny (MALLOC_TRIM_THRESHOLD_=65536) every freed 4 MB array is unmapped and the next one
    faults its pages in again; after steady_malloc, as every sweep task calls it, they are reused."""
    code = """
import resource, sys
import numpy as np
from master.sweeps.runner import steady_malloc

def faults():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(50):
        np.ones(1 << 19)  # 4 MB, freed at once
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

unsteady = faults()
steady_malloc()
faults()  # the first one after it comes from the heap's new top
print(unsteady, faults())
"""
    run = subprocess.run([sys.executable, "-c", code], env={**ENV, "MALLOC_TRIM_THRESHOLD_": "65536"},
                         capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    unsteady, steady = map(int, run.stdout.split())
    assert unsteady >= 50 * 100 and steady < 100, (unsteady, steady)  # hundreds of pages per array, against none


def test_the_documented_dask_worker_command_has_the_worker_settings():
    """docs/sweeps.md's generated `dask worker` line sets, by Dask's own reading of environment variables,
    exactly WORKER_SETTINGS (the local pool's settings)."""
    import re

    import dask
    from docs_tables import block as generated

    from master.sweeps.runner import WORKER_SETTINGS

    block = generated("sweeps.md", "worker-command")
    variables = dict(re.findall(r"\b(DASK_[A-Z_]+)=(\S+)", block))
    assert len(variables) == len(WORKER_SETTINGS)
    collected = dask.config.collect_env(variables)
    assert {key: dask.config.get(key, config=collected) for key in WORKER_SETTINGS} == WORKER_SETTINGS
