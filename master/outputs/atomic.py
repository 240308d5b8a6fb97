"""A file written whole or not at all: the one primitive every output of rhi is written with."""
from __future__ import annotations

import os
import signal
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO, Callable


def umask() -> int:
    """The process's file-creation mask (read from /proc on Linux, else by setting it and back)."""
    try:
        with open("/proc/self/status") as status:
            return next(int(line.split()[1], 8) for line in status if line.startswith("Umask:"))
    except (OSError, StopIteration, ValueError):
        mask = os.umask(0o022)
        os.umask(mask)
        return mask


def atomic_write(path: str | os.PathLike, data: str | bytes | Callable[[BinaryIO], None],
                 place: Callable[[str, Path], None] = os.replace) -> None:
    """Write ``path`` whole or not at all: into a temporary file beside it, then a rename.

    Parameters
    ----------
    path : the file to write (its folder must exist).
    data : text (written as UTF-8), bytes, or a function that writes into the binary file it is
        given (``lambda file: numpy.savez(file, ...)``, ``torch.save``).
    place : how the finished temporary file takes its place (default: a rename; a command's --out FILE:
        rhi.master.outputs.out_file.place_file, which never writes over a file that appeared meanwhile).
    """
    path = Path(path)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as file:
            if callable(data):
                data(file)
            else:
                file.write(data.encode("utf-8") if isinstance(data, str) else data)
        os.chmod(temporary, 0o666 & ~umask())  # mkstemp makes files private; results are ordinary files
        place(temporary, path)
    except BaseException as error:
        if os.path.lexists(temporary):
            os.unlink(temporary)
        if isinstance(error, OSError) and error.filename is None and error.errno is not None:
            raise OSError(error.errno, error.strerror, str(path)) from error  # a full disk names the file
        raise


@contextmanager
def signals_held():
    """SIGINT and SIGTERM wait until the block ends (in the main thread), so a rename pair is never cut."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held = {signal.SIGINT, signal.SIGTERM}
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
