"""Scratch folders in TMPDIR that a killed run cannot leave for good.

:func:`scratch_folder` is ``tempfile.TemporaryDirectory`` with a mark inside, ``.rhi-scratch``: the process's
id and its start time (``/proc/PID/stat``). A SIGKILL leaves the folder; the next scratch folder, of any rhi
command, first removes every ``TMPDIR/rhi_*`` folder whose mark names a process that no longer runs. A folder
without the mark, a link, or another user's is never touched.
"""
from __future__ import annotations

import os
import shutil
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path

MARK = ".rhi-scratch"
PREFIX = "rhi_"  # every scratch folder's name starts with it
MAX_MARK_BYTES = 64


def started(pid: int) -> str | None:
    """The start time of process ``pid`` (clock ticks since boot, ``/proc/PID/stat`` field 22), or None if no
    such process runs (or /proc cannot tell)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as file:
            return file.read().rpartition(")")[2].split()[19]
    except (OSError, IndexError):
        return None


def _identity() -> str:
    return f"{os.getpid()} {started(os.getpid()) or '-'}\n"


def _owner_gone(mark: Path) -> bool:
    """Whether the mark ``mark`` names a process that has ended (a process of that id started at another
    time is another process: the id was reused)."""
    try:
        if not stat.S_ISREG(os.lstat(mark).st_mode):  # a FIFO is never opened
            return False
        with open(mark, "rb") as file:
            fields = file.read(MAX_MARK_BYTES).decode("ascii").split()
    except (OSError, UnicodeDecodeError):
        return False
    if len(fields) != 2 or not fields[0].isdigit():
        return False
    pid, start = int(fields[0]), fields[1]
    if start != "-":
        return started(pid) != start
    try:  # no /proc when it was written: the id alone
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:
        pass
    return False


def clean_stale(prefix: str = PREFIX, root: str | os.PathLike | None = None) -> list[str]:
    """Remove the folders ``root/prefix*`` (default root: TMPDIR) that this user's runs marked and left when
    killed (their process has ended); returns their names."""
    root = Path(root or tempfile.gettempdir())
    removed = []
    try:
        entries = [entry for entry in root.iterdir() if entry.name.startswith(prefix)]
    except OSError:
        return removed
    for entry in entries:
        try:
            info = os.lstat(entry)
        except OSError:
            continue
        if not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid() or not _owner_gone(entry / MARK):
            continue
        shutil.rmtree(entry, ignore_errors=True)
        removed.append(entry.name)
    return removed


@contextmanager
def scratch_folder(prefix: str):
    """A new folder ``TMPDIR/prefix*`` (``prefix`` starting with ``rhi_``), marked as this process's and removed
    when the block ends; the scratch folders that killed runs left are removed first (:func:`clean_stale`)."""
    assert prefix.startswith(PREFIX), prefix
    clean_stale()
    with tempfile.TemporaryDirectory(prefix=prefix) as folder:
        (Path(folder) / MARK).write_text(_identity(), encoding="ascii")
        yield Path(folder)
