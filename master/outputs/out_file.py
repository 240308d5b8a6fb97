"""A command's ``--out FILE``: its name checked against the file system's limit, the file checked before any work,
and the finished file put in its place, never over a file that appeared there meanwhile.

The folders a run writes (DIR, staged and published whole) are :mod:`rhi.master.outputs.files`'.
"""
from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path
from typing import Callable

from rhi.master.cosim import ConfigError
from rhi.master.outputs.atomic import signals_held


# What rhi adds to an output's name for what it makes beside it, the longest of them: its staging folder
# ".NAME.XXXXXXXX.partial" (tempfile's 8 random characters); the others (.old, .probe, .tmp, .lock) are shorter.
NAME_MARGIN = len("..XXXXXXXX.partial")
DEFAULT_NAME_MAX = 255  # bytes, where the file system does not say (Linux's ext4, XFS, btrfs, tmpfs)


def name_max(folder: Path) -> int:
    """The longest name, in bytes, the file system of ``folder`` (or of its nearest existing parent) takes."""
    folder = folder.absolute()
    while not folder.is_dir() and folder != folder.parent:
        folder = folder.parent
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        return DEFAULT_NAME_MAX


def check_name_length(out: str | os.PathLike) -> None:
    """ConfigError unless each part of ``out`` fits the file system's NAME_MAX, the last one with
    NAME_MARGIN to spare for the names rhi makes beside it."""
    path = Path(out)
    limit = name_max(path.parent)
    for number, part in enumerate(path.parts):
        last = number == len(path.parts) - 1
        allowed = limit - NAME_MARGIN if last else limit
        if len(os.fsencode(part)) > allowed:
            shown = part if len(part) <= 24 else part[:20] + "..."
            raise ConfigError(f"--out: the name {shown} has {len(os.fsencode(part))} bytes, over the limit of "
                              f"{allowed} (this file system's NAME_MAX of {limit}" +
                              (f", less {NAME_MARGIN} for the staging name .NAME.XXXXXXXX.partial)" if last else ")"))


def check_output_file(out: str | os.PathLike, noun: str, suffix: str = "", force: bool = False,
                      ours: Callable[[Path], str | None] | None = None) -> Path:
    """``out`` as a Path if a ``noun`` (e.g. "checkpoint file") can be written there, checked before any work:
    a name (ending in ``suffix`` when one is given), not a folder, in a folder that exists and takes new
    files (/proc, read-only, full: refused now, not after the work). A ConfigError names the problem.

    With ``ours`` (a command's --out FILE), an existing file is replaced only with ``force``, and only if
    ``ours(path)`` says rhi wrote it (None; else what it is not: rhi.master.export.own_files); a link is never
    replaced."""
    text = str(out)
    out = Path(out)
    if suffix and (out.suffix != suffix or out.name == suffix):
        raise ConfigError(f"--out {text!r} must be a file name ending in {suffix}")
    if not text.strip():
        raise ConfigError(f"--out is empty: name the {noun} to write")
    check_name_length(out)
    if out.is_dir():
        raise ConfigError(f"--out {text} is a folder; name the {noun} to write")
    if out.exists() and not out.is_file():
        raise ConfigError(f"--out {text} exists and is not a regular file")
    if ours is not None and (out.exists() or out.is_symlink()):
        if not force:
            raise ConfigError(f"--out {text} exists; use --force to replace it (rhi replaces only its own {noun}s)")
        problem = "a symbolic link" if out.is_symlink() else ours(out)
        if problem is not None:
            raise ConfigError(f"--out {text} exists and rhi did not write it ({problem}); --force replaces only "
                              f"rhi's own {noun}s: choose another --out")
    parent = out.absolute().parent
    if not parent.is_dir():
        raise ConfigError(f"cannot write {text}: {parent} {'is not a folder' if parent.exists() else 'does not exist'}")
    try:
        handle, probe = tempfile.mkstemp(dir=parent, prefix=f".{out.name}.", suffix=".probe")
        os.close(handle)
        os.unlink(probe)
    except OSError as error:
        raise ConfigError(f"cannot write into {parent} ({error.strerror or error})") from None
    return out


_CHECKED: dict[str, tuple | None] = {}  # a command's --out FILE, checked -> what was there (None: nothing)


def guard_out_file(out: str | os.PathLike) -> None:
    """Note what is at a command's ``--out FILE`` now, as it is checked before any work: :func:`place_file`
    puts the finished file there only if that is still so (a file that appeared meanwhile is never written
    over)."""
    _CHECKED[str(Path(out).absolute())] = _state(Path(out))


def _state(path: Path) -> tuple | None:
    try:
        info = os.lstat(path)
    except FileNotFoundError:
        return None
    return info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns


def forget_checked() -> None:
    """Start a new run: no --out FILE checked yet (rhi.master.commands.cli.main calls it)."""
    _CHECKED.clear()


def place_file(finished: str | os.PathLike, out: str | os.PathLike) -> None:
    """Put the finished file ``finished`` (beside ``out``, on its file system) at ``out``, never over a file that
    appeared or changed there since :func:`guard_out_file` noted it: where nothing was, by a hard link
    that fails if anything is there now, then the temporary name removed; where rhi's own file was (--force),
    by a rename once it is found unchanged. A file that appeared is left as it is: ConfigError. A path not
    noted (a cache's file, a scratch folder's) is simply renamed onto."""
    out = Path(out)
    key = str(out.absolute())
    if key not in _CHECKED:
        os.replace(finished, out)
        return
    was = _CHECKED.pop(key)
    appeared = ConfigError(f"--out {out} appeared or changed while this command ran; it was left as it is and "
                           "nothing was written there")
    with signals_held():
        if was is not None:
            if _state(out) != was:
                raise appeared
            os.replace(finished, out)
            return
        try:
            os.link(finished, out, follow_symlinks=False)
        except FileExistsError:
            raise appeared from None
        except OSError as error:  # a file system without hard links: checked, then renamed
            if error.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK):
                raise
            if os.path.lexists(out):
                raise appeared from None
            os.replace(finished, out)
            return
        os.unlink(finished)
