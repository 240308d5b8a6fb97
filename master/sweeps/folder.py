"""A sweep's output folder: checked, locked, started over for a new sweep, and its trial records read back.

DIR holds sweep.json (the plan's fingerprint, points and configurations), trials/ID.json (one file
per finished trial, written atomically as it arrives), index.csv, summary.csv and figures/.
A DIR holding a different sweep is refused unless ``force``, which keeps only the trials the new
sweep shares with it and removes only what the older sweep wrote (its .rhi-manifest.json lists each file
rhi wrote, with its sha256: rhi.master.outputs.manifest);
a DIR whose sweep.json rhi did not write, or holding a link where a sweep writes, is refused even with
``force``.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import stat
from contextlib import contextmanager
from pathlib import Path

from rhi.master.cosim import ConfigError
from rhi.master.outputs.files import atomic_write
from rhi.master.outputs.out_file import check_name_length
from rhi.master.outputs.provenance import package_versions
from rhi.master.outputs.manifest import NAME as MANIFEST, Manifest
from rhi.master.outputs.own_paths import LockFile, is_own_mark, make_folder
from rhi.master.sweeps.plan import DEFAULT_TASK, Sweep
from rhi.master.sweeps.tables import MEASURES

COMMAND = "rhi sweep"  # sweep.json's "command": the folder is a sweep's output
OUTPUTS = ("sweep.json", "trials", "figures", "index.csv", "summary.csv")  # what a sweep writes into DIR
MAX_RECORD_BYTES = 16 * 2**20  # a trial record read back; rhi's are a few KiB (a failed trial's traceback included)


@contextmanager
def sweep_folder(out: Path, sweep: Sweep, force: bool):
    """Check, lock and prepare DIR; yields the records already in it that belong to this sweep.

    Refused, even with ``force``: an empty name, the working folder or a folder above it, a file, and a
    non-empty folder that holds no sweep (no sweep.json): a sweep never writes into another's files.
    """
    check_folder(out)
    manifest = out / "sweep.json"
    if out.is_dir() and not manifest.exists() and any(out.iterdir()) and not only_leftovers(out):
        raise ConfigError(f"output folder {out} is not empty and holds no sweep (no sweep.json); --force only "
                          "replaces a sweep: choose another --out")
    if manifest.exists() or manifest.is_symlink():
        old = read_manifest(manifest)
        if old is None:
            raise ConfigError(f"output folder {out} holds a sweep.json that rhi sweep did not write; it is never "
                              "replaced, with or without --force: choose another --out")
    try:
        created = make_folder(out)  # ours to remove again only if this process made it
    except OSError as error:
        raise ConfigError(f"cannot write {out}: {error.strerror or error}") from None
    lock = LockFile(out / ".lock", f"another rhi sweep is writing to {out}")
    try:
        lock.acquire()
    except (ConfigError, OSError) as error:  # another run's, or no lock at all: nothing of this run's to remove
        if created:
            _remove_if_empty(out)
        if isinstance(error, OSError):
            raise ConfigError(f"cannot write {out}: {error.strerror or error}") from None
        raise
    try:
        yield from _prepared(out, sweep, force, manifest)
    except (ConfigError, OSError):  # refused, or a full disk, before any trial ran: a DIR this sweep made, and
        # locked all along, goes again (all of it is ours)
        if created and not any((out / "trials").glob("*.json")):
            lock.release()
            shutil.rmtree(out, ignore_errors=True)
        raise
    finally:
        lock.release()


def _remove_if_empty(folder: Path) -> None:
    try:
        folder.rmdir()
    except OSError:
        pass


def _prepared(out: Path, sweep: Sweep, force: bool, manifest: Path):
    """The locked DIR checked and started over if need be; yields its records and the list of the files rhi
    wrote there (its Manifest, to be added to as the sweep writes; see :func:`sweep_folder`)."""
    old = read_manifest(manifest) if manifest.exists() else None
    previous = old["fingerprint"] if old else None
    if previous is not None and previous != sweep.fingerprint and not force:
        raise ConfigError(f"output folder {out} holds a different sweep (its file or the defaults changed); "
                          "use another --out, or --force to replace it")
    own = Manifest.read(out, COMMAND) or Manifest(out, COMMAND)
    records = read_records(out, sweep)  # checked before anything is removed (start_over keeps every one of them)
    if previous != sweep.fingerprint:
        start_over(out, sweep, old or {}, own)
    else:  # resumed: what it writes over at the end must be rhi's, unchanged (a summary.csv edited meanwhile stays)
        refuse_unproven(out, [name for name in written_by(sweep) if name != "index.csv"], own)
    planned = {f"{trial.id}.json" for trial in sweep.trials}
    for leftover in (out / "trials").glob(".*.tmp"):  # a record's write cut short by a kill; its trial reruns
        match = TEMPORARY.fullmatch(leftover.name)
        if match and match.group(1) in planned and is_own_mark(leftover):  # atomic_write's name; a file, no link
            leftover.unlink()
    yield records, own


# atomic_write's temporary name for a trial record: .ID.json.XXXXXXXX.tmp (tempfile.mkstemp's 8 characters)
TEMPORARY = re.compile(r"\.(.+\.json)\.[A-Za-z0-9_]{8}\.tmp")


def only_leftovers(folder: Path, folders=("trials",)) -> bool:
    """Whether ``folder`` holds nothing but what a run cut short before its first file (a full disk) leaves: an
    empty ``.lock`` and the empty ``folders`` it made; the same command then starts there as in an empty one."""
    for entry in folder.iterdir():
        if entry.is_symlink():
            return False
        if entry.name == ".lock" and stat.S_ISREG(entry.stat().st_mode) and entry.stat().st_size == 0:
            continue
        if entry.name in folders and entry.is_dir() and not any(entry.iterdir()):
            continue
        return False
    return True


def check_folder(out: Path) -> None:
    """ConfigError unless DIR names a folder a sweep may create or use (see :func:`sweep_folder`)."""
    if not str(out).strip():
        raise ConfigError("--out is empty: name a folder for the sweep")
    check_name_length(out)
    resolved, here = Path(out).resolve(), Path.cwd().resolve()
    if resolved == here or resolved in here.parents or resolved == Path(resolved.anchor):
        raise ConfigError(f"output {out} is the working folder or a folder above it; name a folder for the sweep")
    if out.exists() and not out.is_dir():
        raise ConfigError(f"output {out} exists and is not a folder")
    for name in ("", *OUTPUTS, ".lock", MANIFEST):  # a link could lead a write or a removal out of DIR
        if (out / name).is_symlink():
            raise ConfigError(f"output {out / name} is a symbolic link; a sweep writes only into folders of its own")
        if name in ("trials", "figures") and (out / name).exists() and not (out / name).is_dir():
            raise ConfigError(f"output {out / name} exists and is not a folder")
    if not out.absolute().parent.is_dir():
        raise ConfigError(f"cannot write {out}: folder {out.absolute().parent} does not exist")


def read_manifest(path: Path) -> dict | None:
    """sweep.json as rhi sweep wrote it (a JSON object with its command, fingerprint, swept keys and trials
    planned; the command is absent from older ones), else None: a file of another tool's, or damaged."""
    try:
        manifest = json.loads(path.read_text(encoding="utf-8")) if not path.is_symlink() else None
    except (OSError, ValueError, RecursionError):
        return None
    if not isinstance(manifest, dict) or manifest.get("command", COMMAND) != COMMAND:
        return None
    if not (isinstance(manifest.get("fingerprint"), str) and isinstance(manifest.get("swept_keys"), list)
            and isinstance(manifest.get("trials_planned"), int)):
        return None
    return manifest


def written_by(sweep: Sweep) -> list[str]:
    """The files a run of ``sweep`` writes over, relative to DIR: its tables and its plots."""
    return ["index.csv", "summary.csv", *(f"figures/{key}.png" for key in sweep.keys if "/" not in key)]


def start_over(out: Path, sweep: Sweep, old: dict, own: Manifest) -> None:
    """Write the new sweep.json; drop what the older sweep of ``old`` (its sweep.json) wrote, except the
    trials this one shares: only the files its manifest ``own`` lists, unchanged since. A file the new
    sweep would write over that rhi cannot show it wrote (yours, or edited) is refused, naming it, before
    anything is removed; any other file stays."""
    if old:
        refuse_unproven(out, written_by(sweep), own)
        planned = {f"trials/{trial.id}.json" for trial in sweep.trials}
        own.remove_proven(keep=planned | {"sweep.json"})
    (out / "trials").mkdir(exist_ok=True)
    manifest = {"command": COMMAND, "fingerprint": sweep.fingerprint, "task": sweep.task, "swept_keys": sweep.keys,
                "points": [{"point": n, "parameters": p, "configuration": c}
                           for n, (p, c) in enumerate(zip(sweep.points, sweep.configs))],
                "trials_planned": len(sweep.trials), "tasks_planned": len(sweep.chunks),
                "lockstep_batches": sweep.batched, "versions": package_versions()}
    atomic_write(out / "sweep.json", json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    own.folders.add("trials")
    own.add("sweep.json")
    own.save()


def refuse_unproven(out: Path, names: list[str], own: Manifest) -> None:
    """ConfigError naming the files of ``names`` in DIR that a sweep would write over but that rhi cannot show it
    wrote (not in its manifest ``own``, or changed since: a user's, or edited)."""
    blocking = [name for name in names if ((out / name).exists() or (out / name).is_symlink())
                and not own.proven(name)]
    if blocking:
        raise ConfigError(f"output folder {out}: {', '.join(blocking[:5])} would be written over but "
                          f"{'is' if len(blocking) == 1 else 'are'} not what rhi sweep wrote there (not in its "
                          f"{MANIFEST}, or changed since); rhi replaces only its own files: move "
                          f"{'it' if len(blocking) == 1 else 'them'} or choose another --out")


def read_records(out: Path, sweep: Sweep) -> dict[str, dict]:
    """The records in DIR/trials of the sweep's trials (a missing one: not run yet), each checked whole
    (:func:`record_problem`): a file that is not a record as rhi writes one is refused, naming it, before any
    trial runs (a torn file cannot happen with atomic writes)."""
    records = {}
    for trial in sweep.trials:
        path = out / "trials" / f"{trial.id}.json"
        try:
            if not stat.S_ISREG(os.stat(path).st_mode):  # a FIFO would wait forever: never opened
                raise ConfigError(f"trial record {path} is not a regular file; move it away and run the same "
                                  "command again to rerun its trial")
            with open(path, "rb") as file:
                text = file.read(MAX_RECORD_BYTES + 1)
        except FileNotFoundError:
            continue
        except OSError as error:
            raise ConfigError(f"trial record {path} cannot be read: {error.strerror or error}") from None
        record, problem = None, f"over {MAX_RECORD_BYTES} bytes" if len(text) > MAX_RECORD_BYTES else None
        if problem is None:
            try:
                record = json.loads(text.decode("utf-8"))
            except RecursionError:
                problem = "JSON nested too deep"
            except ValueError:  # UnicodeDecodeError is one
                problem = "not JSON"
            else:
                problem = record_problem(record, sweep.task == DEFAULT_TASK)
        if problem:
            raise ConfigError(f"trial record {path} is not one rhi wrote ({problem}); move it away and run the same "
                              "command again to rerun its trial")
        records[trial.id] = record
    return records


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def record_problem(record, default_task: bool = True) -> str | None:
    """What makes ``record`` (a trial record read back) not one rhi writes (None: it is one): a JSON object,
    either ``{"status": "failed", "error": "..."}`` or ``{"status": "ok", "outcome": {...}}``: an outcome whose
    drift_cm, force_n and gamma_final (the tables' measures) are numbers, and of the experiment's own trial
    function (``default_task``) a number for every key, those three among them (NaN and infinities too, as rhi
    writes the times of events that never came); a chunk's ``cpu_s`` a number over its ``batch``, a whole
    number of trials."""
    if not isinstance(record, dict):
        return "not a JSON object"
    status = record.get("status")
    if status == "failed":
        return None if isinstance(record.get("error"), str) else "a failed trial without its error"
    if status != "ok":
        return "its status is neither ok nor failed"
    outcome = record.get("outcome")
    if not isinstance(outcome, dict):
        return "a finished trial without its outcome"
    missing = [key for key in MEASURES if key not in outcome] if default_task else []
    if missing:
        return f"its outcome lacks {missing[0]}"
    wrong = [key for key, value in outcome.items() if (default_task or key in MEASURES) and not _number(value)]
    if wrong:
        return f"its outcome's {wrong[0][:40]} is not a number"
    if "cpu_s" in record and not (_number(record["cpu_s"]) and isinstance(record.get("batch"), int)
                                  and not isinstance(record["batch"], bool) and record["batch"] > 0):
        return "its cpu_s is not a number over a batch of trials"
    return None
