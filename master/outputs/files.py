"""Files that are whole or absent: atomic writes, staging folders published by a rename.

Every file is written to a temporary file in the same folder and then renamed, so a crash leaves
either the old file or the new one, never half of one; a run's folder is staged beside DIR and
renamed into place when complete. A command's single ``--out FILE`` is :mod:`rhi.master.outputs.out_file`'s.
"""
from __future__ import annotations

import errno
import fcntl
import json
import os
import re
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

from rhi.master.cosim import ConfigError
from rhi.master.outputs.atomic import atomic_write, signals_held, umask  # noqa: F401: atomic_write, umask re-exported
from rhi.master.outputs.out_file import check_name_length
from rhi.master.outputs.own_paths import LockFile, is_own_mark, write_own


OUTPUT_COMMAND = "rhi experiment"  # run.json's and the manifest's "command": an experiment's output
# The commands whose output folders --force may replace for one another (each an output_folder run)
OUTPUT_COMMANDS = (OUTPUT_COMMAND, "rhi reach", "rhi phenomenon moving-hand", "rhi phenomenon reach-after")
STAGING_MARK = ".rhi-staging"  # inside a staging folder until it is published: ours, and safe to clean
_ACTIVE: dict[Path, "OutputLock"] = {}  # staging folder -> its lock, while this process writes them
# A write refused by the machine (a full disk or quota, an I/O error): exit status 1, not a refusal of the input
MACHINE_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EFBIG)


def cannot_write(where: Path, error: OSError) -> Exception:
    """The error to raise when ``where`` cannot be written: the machine's (an OSError naming ``where``: a full
    disk, exit status 1) or the input's (ConfigError: no permission, a read-only file system)."""
    if error.errno in MACHINE_ERRORS:
        return OSError(error.errno, error.strerror, str(where))
    return ConfigError(f"cannot write into {where}: {error.strerror or error}")


def foreign_entries(folder: Path) -> list[str]:
    """What in ``folder`` an earlier `rhi experiment` (or another of :data:`OUTPUT_COMMANDS`) cannot be shown to
    have written (empty: all of it is one of their outputs, as its manifest lists it, unchanged;
    rhi.master.outputs.manifest). Without that manifest: every entry."""
    from rhi.master.outputs.manifest import Manifest

    try:
        names = sorted(entry.name for entry in folder.iterdir())
    except OSError:
        return ["(an unreadable folder)"]
    manifest = Manifest.read(folder, OUTPUT_COMMANDS)
    if manifest is None:
        return names or ["nothing"]
    return manifest.unproven()


def check_output(out: str | os.PathLike, force: bool) -> Path:
    """DIR as a Path, if a run may write it: ConfigError naming the reason otherwise.

    Refused even with ``force``: an empty name, the working folder or a folder above it (``.``, ``..``),
    a file, and a non-empty folder that is not an earlier output of `rhi experiment` (foreign_entries).
    """
    if not str(out).strip():
        raise ConfigError("--out is empty: name a new folder for the results")
    check_name_length(out)
    path = Path(out)
    resolved, here = path.resolve(), Path.cwd().resolve()
    if resolved == here or resolved in here.parents or resolved == Path(resolved.anchor):
        raise ConfigError(f"output {out} is the working folder or a folder above it; name a new folder for the "
                          "results (--force never replaces these)")
    if path.exists() and not path.is_dir():
        raise ConfigError(f"output {out} exists and is not a folder")
    if path.is_symlink():
        raise ConfigError(f"output {out} is a symbolic link; name the folder itself")
    if path.is_dir() and any(path.iterdir()):
        if not force:
            raise ConfigError(f"output folder {out} exists and is not empty (use --force to replace it)")
        foreign = foreign_entries(path)
        if foreign:
            shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
            raise ConfigError(f"output folder {out} is not an earlier rhi experiment output (it holds {shown}); "
                              "--force replaces only rhi's own results: move it or choose another --out")
    parent = path.absolute().parent
    if not parent.is_dir():
        raise ConfigError(f"cannot write {out}: folder {parent} does not exist")
    for folder in (path, parent):  # checked now: a rename onto it would fail only once the run is done
        if folder.is_dir() and unchangeable(folder):
            raise ConfigError(f"cannot write {out}: {folder} is immutable or append-only (chattr +i, +a); rhi "
                              "replaces DIR by a rename, which it forbids")
    return path


FS_IOC_GETFLAGS = 0x80086601  # Linux's ioctl reading a file's attributes (lsattr), _IOR('f', 1, long)
UNCHANGEABLE = 0x10 | 0x20  # FS_IMMUTABLE_FL, FS_APPEND_FL: no rename onto or out of it


def unchangeable(folder: Path) -> bool:
    """Whether ``folder`` is immutable or append-only (Linux file attributes); False where they cannot be read."""
    import array

    try:
        descriptor = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return False
    try:
        flags = array.array("l", [0])
        fcntl.ioctl(descriptor, FS_IOC_GETFLAGS, flags, True)
        return bool(flags[0] & UNCHANGEABLE)
    except OSError:
        return False
    finally:
        os.close(descriptor)


class OutputLock:
    """An exclusive lock on DIR, held while a run writes it: a file ``.DIR.lock`` beside DIR, flock'ed
    (released by the kernel if the process dies), removed when the run ends if it is the one this run made
    (rhi.master.outputs.own_paths.LockFile: never through a link, never a file of someone else's)."""

    def __init__(self, out: Path):
        self.out = out
        self.path = out.absolute().parent / f".{out.name}.lock"
        self.lock = LockFile(self.path, f"another rhi run is writing {out} (it holds {self.path}); wait for it to "
                                        "end or choose another --out")

    def acquire(self) -> "OutputLock":
        """Take the lock without waiting and return it; ConfigError if another run holds it or it cannot be made."""
        try:
            self.lock.acquire()
        except OSError as error:
            raise cannot_write(self.path.parent, error) from None
        return self

    def release(self) -> None:
        """Remove the lock file (if this run made it) and close it, which releases the lock; nothing if not held."""
        self.lock.release()


def clean_stale(out: Path) -> list[str]:
    """Remove what runs of ours into DIR left beside it when killed: ``.DIR.XXXXXXXX.partial`` staging folders
    holding our mark (or nothing) and ``.DIR.XXXXXXXX.old`` earlier outputs; call it holding DIR's lock."""
    pattern = re.compile(re.escape(f".{out.name}.") + r"[A-Za-z0-9_]{8}\.(partial|old)")
    removed = []
    parent = out.absolute().parent
    for entry in parent.iterdir():
        match = pattern.fullmatch(entry.name)
        if not match or entry.is_symlink() or not entry.is_dir():
            continue
        ours = is_own_mark(entry / STAGING_MARK) or not any(entry.iterdir()) if match.group(1) == "partial" \
            else not foreign_entries(entry)
        if ours:
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry.name)
    return removed


@contextmanager
def output_folder(out: str | os.PathLike, force: bool):
    """Write DIR whole or not at all: check it (:func:`check_output`), lock it, clean what killed runs left,
    and yield an empty staging folder beside it; when the block ends without an error, publish the staging
    folder as DIR (re-checking that nothing else appeared there meanwhile), else remove it."""
    path = check_output(out, force)
    lock = OutputLock(path).acquire()
    try:
        clean_stale(path)
        existed = path.is_dir() and any(path.iterdir())
        staging = _make_staging(path)
        _ACTIVE[staging] = lock
        try:
            yield staging
            from rhi.master.outputs.manifest import Manifest

            Manifest.of(staging, staged_command(staging)).save()  # the last file: what the run wrote, listed
            publish(staging, path, replacing=existed, force=force)
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
        finally:
            _ACTIVE.pop(staging, None)
    finally:
        lock.release()


def staged_command(staging: Path) -> str:
    """The command a staging folder's run.json names, if one of OUTPUT_COMMANDS; else OUTPUT_COMMAND."""
    try:
        command = json.loads((staging / "run.json").read_text(encoding="utf-8")).get("command")
    except (OSError, ValueError, AttributeError):
        command = None
    return command if command in OUTPUT_COMMANDS else OUTPUT_COMMAND


def _make_staging(out: Path) -> Path:
    """A new staging folder on DIR's own file system: beside DIR, or inside it when DIR is a mount point
    (a container's volume), which cannot be renamed onto."""
    parent = out.absolute() if out.is_dir() and os.path.ismount(out) else out.absolute().parent
    try:
        staging = Path(tempfile.mkdtemp(dir=parent, prefix=f".{out.name}.", suffix=".partial"))
    except OSError as error:
        raise cannot_write(parent, error) from None
    try:
        write_own(staging / STAGING_MARK, f"{os.getpid()}\n")
    except OSError as error:  # a full disk makes the folder but not the file: the folder goes again
        shutil.rmtree(staging, ignore_errors=True)
        raise cannot_write(parent, error) from None
    staging.chmod(0o777 & ~umask())  # mkdtemp makes it private; the published folder is an ordinary one
    return staging


def publish(staging: Path, out: str | os.PathLike, replacing: bool | None = None, force: bool = True) -> None:
    """Put the finished staging folder in DIR's place, in one rename.

    DIR must be as it was checked when the run began: absent or empty, or (``replacing``) an earlier
    output of ours, which is moved aside first and removed once the new one is in place. Anything else
    there now (another program wrote it meanwhile) is left alone and the run is not published.
    """
    out = Path(out)
    (staging / STAGING_MARK).unlink(missing_ok=True)
    if staging.absolute().parent == out.absolute():
        return _publish_inside(staging, out, force)
    if replacing is None:
        replacing = out.is_dir() and any(out.iterdir())
    aside = None
    with signals_held():
        if out.is_dir() and not out.is_symlink() and any(out.iterdir()):
            foreign = foreign_entries(out)
            if not replacing or foreign or not force:
                raise ConfigError(f"output folder {out} was written by something else while this run went on "
                                  f"(it holds {', '.join(foreign[:5]) or 'another rhi output'}); it was left as it "
                                  "is and this run's results were not published")
            aside = Path(tempfile.mkdtemp(dir=out.absolute().parent, prefix=f".{out.name}.", suffix=".old"))
            os.replace(out, aside)  # onto the empty folder mkdtemp made
        try:
            os.replace(staging, out)  # onto nothing or an empty folder; a folder with content refuses
        except OSError as error:
            if aside is not None:
                os.replace(aside, out)
            if error.errno in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
                raise ConfigError(f"output {out} appeared while this run went on; it was left as it is and this "
                                  "run's results were not published") from None
            raise
    if aside is not None:
        shutil.rmtree(aside, ignore_errors=True)


def _publish_inside(staging: Path, out: Path, force: bool) -> None:
    """:func:`publish` for a staging folder inside DIR (a mount point): an earlier output of ours there is moved
    into a folder aside, inside DIR too, then each new entry renamed into DIR, then the old one removed."""
    aside = None
    with signals_held():
        others = [entry for entry in out.iterdir() if entry.name != staging.name]
        if others:
            foreign = [name for name in foreign_entries(out) if name != staging.name]
            if foreign or not force:
                raise ConfigError(f"output folder {out} was written by something else while this run went on "
                                  f"(it holds {', '.join(foreign[:5]) or 'another rhi output'}); it was left as it "
                                  "is and this run's results were not published")
            aside = Path(tempfile.mkdtemp(dir=out, prefix=f".{out.name}.", suffix=".old"))
            for entry in others:
                os.replace(entry, aside / entry.name)
        for entry in sorted(staging.iterdir()):
            os.replace(entry, out / entry.name)
        staging.rmdir()
    if aside is not None:
        shutil.rmtree(aside, ignore_errors=True)


def abandon_staging() -> None:
    """Remove every staging folder this process is writing and release its lock (the process is ending)."""
    for staging, lock in list(_ACTIVE.items()):
        shutil.rmtree(staging, ignore_errors=True)
        lock.release()
    _ACTIVE.clear()
