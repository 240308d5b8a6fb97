"""A sweep's output folder: checked, locked, started over for a new sweep, and its trial records read back.

DIR holds sweep.json (the plan's fingerprint, points and configurations), trials/ID.json (one file
per finished trial, written atomically as it arrives), index.csv, summary.csv and figures/.
A DIR holding a different sweep is refused unless ``force``, which keeps only the trials the new
sweep shares with it.
"""
from __future__ import annotations

import fcntl
import json
from contextlib import contextmanager
from pathlib import Path

from master.cosim import ConfigError
from master.outputs.files import atomic_write, package_versions
from master.sweeps.plan import Sweep


@contextmanager
def sweep_folder(out: Path, sweep: Sweep, force: bool):
    """Check, lock and prepare DIR; yields the records already in it that belong to this sweep.

    Refused, even with ``force``: an empty name, the working folder or a folder above it, a file, and a
    non-empty folder that holds no sweep (no sweep.json): a sweep never writes into another's files.
    """
    check_folder(out)
    manifest = out / "sweep.json"
    if out.is_dir() and not manifest.exists() and any(out.iterdir()):
        raise ConfigError(f"output folder {out} is not empty and holds no sweep (no sweep.json); --force only "
                          "replaces a sweep: choose another --out")
    try:
        out.mkdir(exist_ok=True)
        lock = open(out / ".lock", "w")
    except OSError as error:
        raise ConfigError(f"cannot write {out}: {error.strerror or error}") from None
    with lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ConfigError(f"another rhi sweep is writing to {out}") from None
        try:
            previous = json.loads(manifest.read_text()).get("fingerprint") if manifest.exists() else None
        except (OSError, ValueError):
            previous = "unreadable"
        if previous is not None and previous != sweep.fingerprint and not force:
            raise ConfigError(f"output folder {out} holds a different sweep (its file or the defaults changed); "
                              "use another --out, or --force to replace it")
        if previous != sweep.fingerprint:
            start_over(out, sweep)
        for leftover in (out / "trials").glob(".*.tmp"):  # a write cut short by a kill; its trial reruns
            leftover.unlink()
        yield read_records(out, sweep)


def check_folder(out: Path) -> None:
    """ConfigError unless DIR names a folder a sweep may create or use (see :func:`sweep_folder`)."""
    if not str(out).strip():
        raise ConfigError("--out is empty: name a folder for the sweep")
    resolved, here = Path(out).resolve(), Path.cwd().resolve()
    if resolved == here or resolved in here.parents or resolved == Path(resolved.anchor):
        raise ConfigError(f"output {out} is the working folder or a folder above it; name a folder for the sweep")
    if out.exists() and not out.is_dir():
        raise ConfigError(f"output {out} exists and is not a folder")
    if not out.absolute().parent.is_dir():
        raise ConfigError(f"cannot write {out}: folder {out.absolute().parent} does not exist")


def start_over(out: Path, sweep: Sweep) -> None:
    """Write the new manifest; drop every file of an older sweep except trials this one shares."""
    (out / "trials").mkdir(exist_ok=True)
    planned = {trial.id for trial in sweep.trials}
    for path in (out / "trials").glob("*.json"):
        if path.stem not in planned:
            path.unlink()
    for name in ("index.csv", "summary.csv"):
        (out / name).unlink(missing_ok=True)
    if (out / "figures").is_dir():  # the sweep's plots only; anything else put there stays
        for plot in (out / "figures").glob("*.png"):
            plot.unlink()
        if not any((out / "figures").iterdir()):
            (out / "figures").rmdir()
    manifest = {"fingerprint": sweep.fingerprint, "task": sweep.task, "swept_keys": sweep.keys,
                "points": [{"point": n, "parameters": p, "configuration": c}
                           for n, (p, c) in enumerate(zip(sweep.points, sweep.configs))],
                "trials_planned": len(sweep.trials), "tasks_planned": len(sweep.chunks),
                "lockstep_batches": sweep.batched, "versions": package_versions()}
    atomic_write(out / "sweep.json", json.dumps(manifest, indent=1, sort_keys=True) + "\n")


def read_records(out: Path, sweep: Sweep) -> dict[str, dict]:
    records = {}
    for trial in sweep.trials:
        path = out / "trials" / f"{trial.id}.json"
        try:
            records[trial.id] = json.loads(path.read_text())
        except (OSError, ValueError):  # missing; a torn file cannot happen with atomic writes
            continue
    return records
