"""The sweep's rate against the lockstep experiment's, for ``rhi bench``.

The protocol's trials (both decoders, every condition x stimulation, ``sweep_trials`` each) run twice
on this machine with the same decoders (the trained defaults when at hand, else untrained seeded ones):
first in lockstep, one batch per decoder side by side as ``rhi experiment`` runs them; then as a sweep,
``rhi sweep`` in a child process on its local pool (one single-threaded worker per core; one task per
decoder, the sweep's default chunks). Both use the same number of processes. The sweep's rate is
reported twice: over the whole command (Python start-up, the pool's start and the record files
included) and over its task window, from the first task's start to the last one's end as the trial
records give them (what a long sweep converges to); the target is judged on the task window. The
bench cannot import rhi.master.sweeps (the same layer), hence the child.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from rhi.components.body import kinematics
from rhi.components.vision import checkpoint
from rhi.components.vision.component import available_cores
from rhi.components.vision.networks import build, preset, sizes_dict
from rhi.master.tasks import illusion as experiment
from rhi.master import config as configuration
from rhi.master.tasks.illusion import runner
from rhi.master.runtime.pool import process_count
from rhi.master.decoders.training_data import HALF_RANGES
from rhi.master.outputs.files import atomic_write
from rhi.master.runtime.context import RunContext

KINDS = ("conv", "vae")


def untrained_checkpoint(kind: str, preset_name: str, resolution: int, seed: int, folder: Path) -> str:
    """A checkpoint file of an untrained decoder of ``kind`` (torch seed ``seed``), usable by any process."""
    torch.manual_seed(seed)
    model = build(kind, preset_name, resolution)
    metadata = {"kind": kind, "preset": preset_name, "sizes": sizes_dict(preset(preset_name)),
                "resolution": resolution, "rest_pose": [float(a) for a in kinematics.REST_POSE],
                "half_ranges": [float(a) for a in HALF_RANGES], "data_hash": "untrained",
                "validation_mse": float("nan"), "seconds": 0.0}
    path = folder / f"{kind}-untrained-{preset_name}-r{resolution}.pt"
    atomic_write(path, lambda file: checkpoint.write(file, model, metadata))
    return str(path)


def sweep_overrides(settings, checkpoints: dict[str, str]) -> dict:
    """The configuration both runs use: the defaults at the sweep preset's resolution and size."""
    return {"experiment.resolution": settings.sweep_preset[1], "experiment.steps": settings.sweep_steps,
            "experiment.trials": settings.sweep_trials, "experiment.decoders": list(KINDS),
            **{f"decoder.{kind}_checkpoint": path for kind, path in checkpoints.items()}}


def lockstep_run(config: dict, checkpoints: dict[str, str], processes: int) -> dict:
    """Every trial of ``config``'s protocol as ``rhi experiment`` runs them: one lockstep batch per decoder,
    side by side on ``processes`` single-threaded workers (one after the other here when 1). The time is the
    batches' own, from the first one's start to the last one's end (the workers' start excluded, as the
    sweep's task window excludes its pool's)."""
    seconds = runner.run(config, checkpoints, context=RunContext(processes=processes))[3]
    side_by_side = process_count(len(seconds), processes) > 1
    total = max(seconds.values()) if side_by_side else sum(seconds.values())
    trials = len(experiment.plan(config))
    return {"trials": trials, "processes": process_count(len(seconds), processes), "seconds": total,
            "per_decoder_s": seconds, "agent_steps_per_s": trials * config["experiment"]["steps"] / total}


def sweep_file_text(overrides: dict, workers: int) -> str:
    """A sweep file of one point: ``overrides`` (dotted keys) as its tables, then ``[sweep]``."""
    tables: dict[str, list[str]] = {}
    for key, value in overrides.items():
        table, _, name = key.partition(".")
        tables.setdefault(table, []).append(f"{name} = {json.dumps(value)}")
    lines = [line for table, entries in tables.items() for line in (f"[{table}]", *entries)]
    return "\n".join([*lines, "[sweep]", f"workers = {workers}"]) + "\n"


def sweep_run(text: str, folder: Path, trials: int, steps: int) -> dict:
    """``rhi sweep`` of the file ``text`` in a child process; its wall time and its task window."""
    (folder / "sweep.toml").write_text(text)
    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "PYTHONPATH": root + os.pathsep + os.environ.get("PYTHONPATH", "")}
    began = time.perf_counter()
    child = subprocess.run([sys.executable, "-m", "rhi", "sweep", "--config", str(folder / "sweep.toml"),
                            "--out", str(folder / "out")], capture_output=True, text=True, env=env, cwd=folder)
    wall = time.perf_counter() - began
    if child.returncode:
        raise RuntimeError(f"the bench's sweep failed: {child.stderr.strip().splitlines()[-1:]}")
    records = [json.loads(path.read_text()) for path in (folder / "out" / "trials").glob("*.json")]
    if len(records) != trials or any(record["status"] != "ok" for record in records):
        raise RuntimeError(f"the bench's sweep wrote {len(records)} records for {trials} trials, or a failure")
    window = max(r["started_at"] + r["elapsed_s"] for r in records) - min(r["started_at"] for r in records)
    return {"wall_s": wall, "agent_steps_per_s": trials * steps / wall, "task_window_s": window,
            "window_agent_steps_per_s": trials * steps / window,
            "tasks": len({(r["started_at"], r["host"], r["decoder"]) for r in records}),
            "largest_task": max(r["batch"] for r in records)}


def trained_checkpoints(preset_name: str, resolution: int) -> dict[str, str] | None:
    """The trained decoders of the defaults at this network preset and resolution, cached or shipped; else None."""
    from rhi.master.decoders.cache import checkpoint_path
    config = configuration.load(overrides={"experiment.resolution": resolution, "train.preset": preset_name})
    paths = {kind: checkpoint_path(kind, config) for kind in KINDS}
    return paths if all(os.path.isfile(path) for path in paths.values()) else None


def sweep_rate(settings) -> dict:
    """The protocol as a sweep on the local pool against the same trials in lockstep, with the trained decoders
    when ``sweep_trained`` and they are at hand (an untrained decoder barely moves mu, so the fast mode's batches
    are short and the fixed costs weigh more), else untrained ones."""
    preset_name, resolution = settings.sweep_preset
    workers = settings.sweep_workers or available_cores()
    with tempfile.TemporaryDirectory(prefix="rhi_bench_sweep_") as name:
        folder = Path(name)
        checkpoints = settings.sweep_trained and trained_checkpoints(preset_name, resolution)
        weights = "trained: " + ", ".join(map(os.path.basename, checkpoints.values())) if checkpoints else \
            f"untrained, torch seed {settings.seed}"
        checkpoints = checkpoints or {kind: untrained_checkpoint(kind, preset_name, resolution, settings.seed, folder)
                                      for kind in KINDS}
        overrides = sweep_overrides(settings, checkpoints)
        lockstep = lockstep_run(configuration.load(overrides=overrides), checkpoints, workers)
        sweep = sweep_run(sweep_file_text(overrides, workers), folder, lockstep["trials"], settings.sweep_steps)
    return {"preset": preset_name, "resolution": resolution, "weights": weights,
            "trials": lockstep["trials"], "steps": settings.sweep_steps, "workers": workers,
            "lockstep": lockstep, "sweep": sweep,
            "window_vs_lockstep": sweep["window_agent_steps_per_s"] / lockstep["agent_steps_per_s"],
            "wall_vs_lockstep": sweep["agent_steps_per_s"] / lockstep["agent_steps_per_s"]}
