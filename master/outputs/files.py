"""Files that are whole or absent: atomic writes, staging folders published by a rename, provenance.

Every file is written to a temporary file in the same folder and then renamed, so a crash leaves
either the old file or the new one, never half of one; a run's folder is staged beside DIR and
renamed into place when complete.
"""
from __future__ import annotations

import os
import platform
import shutil
import sys
import tempfile
from importlib import metadata
from pathlib import Path
from typing import BinaryIO, Callable

from master.cosim import ConfigError

PACKAGES = ("numpy", "scipy", "torch", "pymunk", "pillow", "fmpy", "pythonfmu", "matplotlib", "dask", "rhi")


def umask() -> int:
    """The process's file-creation mask (read from /proc on Linux, else by setting it and back)."""
    try:
        with open("/proc/self/status") as status:
            return next(int(line.split()[1], 8) for line in status if line.startswith("Umask:"))
    except (OSError, StopIteration, ValueError):
        mask = os.umask(0o022)
        os.umask(mask)
        return mask


def atomic_write(path: str | os.PathLike, data: str | bytes | Callable[[BinaryIO], None]) -> None:
    """Write ``path`` whole or not at all: into a temporary file beside it, then a rename.

    Parameters
    ----------
    path : the file to write (its folder must exist).
    data : text (written as UTF-8), bytes, or a function that writes into the binary file it is
        given (``lambda file: numpy.savez(file, ...)``, ``torch.save``).
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
        os.replace(temporary, path)
    except BaseException:
        os.unlink(temporary)
        raise


def package_versions() -> dict[str, str]:
    versions = {"python": sys.version.split()[0], "platform": platform.platform()}
    for package in PACKAGES:
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            pass
    return versions


def staging_folder(out: str | os.PathLike, force: bool) -> Path:
    """Check DIR can be written and return an empty staging folder beside it."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"output {out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise ConfigError(f"output folder {out} exists and is not empty (use --force to replace it)")
    parent = out.absolute().parent
    if not parent.is_dir():
        raise ConfigError(f"cannot write {out}: folder {parent} does not exist")
    try:
        staging = Path(tempfile.mkdtemp(dir=parent, prefix=f".{out.name}.", suffix=".partial"))
    except OSError as error:
        raise ConfigError(f"cannot write into {parent}: {error.strerror}") from None
    staging.chmod(0o777 & ~umask())  # mkdtemp makes it private; the published folder is an ordinary one
    return staging


def publish(staging: Path, out: str | os.PathLike) -> None:
    """Replace DIR by the finished staging folder."""
    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    os.replace(staging, out)
