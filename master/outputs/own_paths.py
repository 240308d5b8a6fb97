"""rhi's own bookkeeping files (locks, markers, manifests, staging names), opened, made and removed never
through a link (docs/safety.md).

Every such file is opened with O_NOFOLLOW, so a link planted at its name (to a file of the user's, or a
dangling one to a file not there yet) is refused with one line instead of followed; a file rhi makes is made
with O_EXCL (never through any link, never one that is there already); and a file is removed only when this
process made it and it is still the very file it made (same device and inode, a regular file), so a user's
file or link of that name is never deleted.
"""
from __future__ import annotations

import errno
import fcntl
import os
import stat
from pathlib import Path

from rhi.master.cosim import ConfigError

NOFOLLOW = os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)


def open_own(path: str | os.PathLike, flags: int, mode: int = 0o666) -> int:
    """A descriptor of rhi's own file ``path``, opened with ``flags`` never through a link: a link there (or a
    FIFO, a device, a folder) is a ConfigError naming it; OSError otherwise (FileNotFoundError, FileExistsError
    with O_EXCL). A FIFO is opened without waiting (O_NONBLOCK, cleared once it is known to be a file)."""
    try:
        descriptor = os.open(path, flags | NOFOLLOW | os.O_NONBLOCK, mode)
    except OSError as error:
        if error.errno == errno.ELOOP or os.path.islink(path):
            raise ConfigError(f"{path} is a symbolic link; rhi never opens its own files (locks, markers, "
                              "manifests) through one: remove it") from None
        raise
    if not stat.S_ISREG(os.fstat(descriptor).st_mode):
        os.close(descriptor)
        raise ConfigError(f"{path} exists and is not a regular file; rhi keeps its own files (locks, markers, "
                          "manifests) there: remove it")
    fcntl.fcntl(descriptor, fcntl.F_SETFL, fcntl.fcntl(descriptor, fcntl.F_GETFL) & ~os.O_NONBLOCK)
    return descriptor


def create_own(path: str | os.PathLike, mode: int = 0o666) -> int:
    """A descriptor of the new file ``path`` this process makes (O_EXCL: never one already there, never
    through a link; FileExistsError then)."""
    return open_own(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, mode)


def write_own(path: str | os.PathLike, text: str) -> None:
    """Make the new file ``path`` (a marker) holding ``text``, never through a link nor over a file there."""
    descriptor = create_own(path)
    with os.fdopen(descriptor, "w", encoding="utf-8") as file:
        file.write(text)


def is_own_mark(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a regular file itself, not a link to one (a marker rhi may trust as its own)."""
    try:
        return stat.S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False


def identity(descriptor: int) -> tuple[int, int]:
    """(device, inode) of an open file: what :func:`remove_own` checks before removing it."""
    info = os.fstat(descriptor)
    return info.st_dev, info.st_ino


def remove_own(path: str | os.PathLike, made: tuple[int, int]) -> bool:
    """Remove ``path`` if it is still the regular file ``made`` (:func:`identity` of the file this process
    made); anything else there (a link, another file, nothing) stays. Whether it was removed."""
    try:
        info = os.lstat(path)
        if stat.S_ISREG(info.st_mode) and (info.st_dev, info.st_ino) == made:
            os.unlink(path)
            return True
    except OSError:
        pass
    return False


def make_folder(path: str | os.PathLike) -> bool:
    """Make the folder ``path`` if it is not there: True if this process made it (and so owns all of it until it
    publishes something), False if it was there already (whoever made it, even a moment ago)."""
    try:
        os.mkdir(path)
    except FileExistsError:
        if os.path.islink(path) or not os.path.isdir(path):
            raise ConfigError(f"{path} exists and is not a folder") from None
        return False
    return True


class LockFile:
    """An exclusive lock: the empty file ``path``, flock'ed without waiting (released by the kernel if the
    process dies). Made with O_EXCL where absent; an empty regular file there already (a killed run's lock) is
    taken over only once locked, removed, and made anew, so that the lock this process holds is always one it
    made; anything else at ``path`` (a link, a file with content, a FIFO) is refused. :meth:`release` removes
    the file only if it is still the one this process made."""

    def __init__(self, path: str | os.PathLike, busy: str):
        self.path, self.busy = Path(path), busy
        self.descriptor: int | None = None
        self.made: tuple[int, int] | None = None

    def acquire(self) -> "LockFile":
        """Take the lock and return it; ConfigError (``busy``) if another process holds it; ConfigError if a
        link or a foreign file is at ``path``; OSError if it cannot be made."""
        for _ in range(8):
            try:
                descriptor, ours = create_own(self.path), True
            except FileExistsError:
                try:
                    descriptor, ours = open_own(self.path, os.O_RDONLY), False
                except FileNotFoundError:  # removed meanwhile by a run that just ended: try again
                    continue
            try:
                fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(descriptor)
                raise ConfigError(self.busy) from None
            made = identity(descriptor)
            try:
                here = os.lstat(self.path)
                current = (here.st_dev, here.st_ino) == made
            except FileNotFoundError:
                current = False
            if current and ours:
                self.descriptor, self.made = descriptor, made
                return self
            if current:  # a lock a killed run left: ours to replace only if it is a lock as rhi makes them
                if os.fstat(descriptor).st_size:
                    os.close(descriptor)
                    raise ConfigError(f"{self.path} exists and is not rhi's lock file (it is not empty); "
                                      "move it away")
                remove_own(self.path, made)
            os.close(descriptor)
        raise ConfigError(f"cannot lock {self.path}: other runs keep replacing it")

    def release(self) -> None:
        """Remove the lock file if it is still the one this process made, then close it (which releases the
        lock); nothing if it is not held."""
        if self.descriptor is not None:
            remove_own(self.path, self.made)  # while still holding it: a run that opened it sees another inode
            os.close(self.descriptor)
            self.descriptor = self.made = None

    def __enter__(self) -> "LockFile":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
