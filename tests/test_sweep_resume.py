"""Sweeps without a cluster: grid expansion and validation, the lockstep chunks fixed by the file, kill and
resume (bitwise), a failing trial's chunk, the tasks' heap, the documented worker command."""
import csv
import hashlib
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from rhi.master.sweeps import plan as sweeps
from rhi.master.cosim import ConfigError
from rhi.master import config as configuration
from rhi.master.tasks.illusion import trial_seed
from rhi.master.commands.sweep import run as run_sweep
from tests.in_process import rhi_in_process
from tests.sweep_files import ENV, args, batched_file, command, expected, records, single_core, sweep_file


@pytest.fixture(scope="module")
def quick_decoders(quick_cache):
    """The session's --quick conv and vae checkpoints, named in the sweep files."""
    return {kind: str(next(quick_cache.glob(f"{kind}-*.pt"))) for kind in ("conv", "vae")}


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
        "sweep point 1 (decoder.visual_variance=-2.0): decoder.visual_variance must be at least 1e-12 (the "
        "decoder's range), got -2.0")
    assert "non-empty list" in error(grid={"conditions.left": []})
    assert "points 0 and 1 are the same" in error(points=[{"conditions.left": -0.2}, {"conditions.left": -0.2}])
    assert "cannot be imported" in error(task="no_such_task")
    (tmp_path / "typo.toml").write_text("[sweep]\ntrails = 3\n")
    with pytest.raises(ConfigError, match=r"unknown sweep key sweep.trails \(did you mean sweep.trials\?\)"):
        sweeps.load(tmp_path / "typo.toml")


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


def test_chunks_are_fixed_by_the_file_alone(tmp_path):
    """Per point and decoder, consecutive near-equal chunks of at most sweep.batch; ids name the chunk."""
    (tmp_path / "unused.pt").touch()  # loading a plan checks that a named checkpoint exists, and opens none
    checkpoints = {"conv": str(tmp_path / "unused.pt"), "vae": str(tmp_path / "unused.pt")}
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
                                     grid={"conditions.left": [-0.15, -0.3, -0.4]}, batch=3))
    assert {t.id for t in sweep.trials} < {t.id for t in wider.trials}
    # another task runs trials one by one: chunks of one; sweep.batch is refused for it
    single = sweeps.load(sweep_file(tmp_path / "f.toml", trials=3))
    assert not single.batched and single.chunks == [[n] for n in range(len(single.trials))]
    bad = sweep_file(tmp_path / "b.toml")
    bad.write_text(bad.read_text() + "batch = 2\n")  # into its [sweep] table
    with pytest.raises(ConfigError, match=r"sweep.batch applies to the default task .* once per trial"):
        sweeps.load(bad)


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
    # the rerun in this process (tests/in_process.py; one worker: no pool), without seconds of start-up
    rerun = rhi_in_process(["sweep", "--config", str(path), "--out", str(out)], tmp_path, {})
    assert rerun.status == 0, rerun.stderr
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
    from rhi.master.cosim import SimulationError
    from rhi.master.tasks.illusion import measures, plan, run_batch
    from rhi.master.tasks.illusion import runner
    from rhi.master.decoders.cache import decoder_component
    from rhi.master.tasks.illusion.measures import end_of_trial

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

    def blaming(decoder, batch, given, body=None):
        calls.append(len(batch))
        if blamed in batch:
            raise SimulationError("body", 0.4, "NaN in this trial", trials=(batch.index(blamed),))
        return run_batch(decoder, batch, given, body)

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
from rhi.master.sweeps.runner import steady_malloc


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

    from rhi.master.sweeps.runner import WORKER_SETTINGS

    block = generated("sweeps.md", "worker-command")
    variables = dict(re.findall(r"\b(DASK_[A-Z_]+)=(\S+)", block))
    assert len(variables) == len(WORKER_SETTINGS)
    collected = dask.config.collect_env(variables)
    assert {key: dask.config.get(key, config=collected) for key in WORKER_SETTINGS} == WORKER_SETTINGS


def test_the_index_is_rewritten_at_most_once_in_ten_times_its_own_duration():
    from rhi.master.sweeps.run import INDEX_EVERY_S, INDEX_SHARE, index_due

    assert (INDEX_EVERY_S, INDEX_SHARE) == (2.0, 10.0)
    # a cheap rewrite (0.01 s): every 2 s, as always
    assert not index_due(101.9, 100.0, 0.01) and index_due(102.1, 100.0, 0.01)
    # a rewrite of 0.85 s (24 000 trials' index): not before 8.5 s, so at most 0.85 / (8.5 + 0.85) = 9 % of the time
    assert not index_due(108.4, 100.0, 0.85) and index_due(108.6, 100.0, 0.85)
