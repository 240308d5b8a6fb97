"""Zip archives from elsewhere (FMUs, SSP packages, checkpoints), read and unpacked safely.

Every archive rhi reads goes through :func:`check_archive` first: each member must name a place inside
the folder it unpacks into (no absolute name, drive letter, backslash, ``..`` or empty part, no two
members for one place), must be an ordinary file or folder (no symbolic link, device, FIFO or socket),
and the sizes are bounded (:data:`LIMITS`), so that a small file cannot unpack into gigabytes (a zip
bomb). A refused archive raises one :class:`ArchiveError` naming the archive, the member and the rule,
before any byte is written. :func:`extract` then unpacks it into a new folder, refusing to write
through any link, with every member's size enforced as it is copied. :func:`pack` applies the same
rules to an archive rhi writes from another's files.

Example::

    folder = extract("Body.fmu", tempfile.mkdtemp())   # ArchiveError: "Body.fmu: member '../x' ..."
"""
from __future__ import annotations

import os
import stat
import zipfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from .component import ComponentError


@dataclass(frozen=True)
class Limits:
    """Bounds on what one archive may unpack into.

    members: how many entries. member_bytes: the largest entry, unpacked. total_bytes: all entries
    together, unpacked. ratio: the largest unpacked / packed size of an entry of over ``ratio_floor``
    bytes (deflate reaches about 1000:1 only on repetitive filler; trained weights pack about 1.1:1,
    Python sources 3-5:1).
    """

    members: int = 10_000
    member_bytes: int = 512 * 2**20
    total_bytes: int = 2**30
    ratio: float = 100.0
    ratio_floor: int = 2**20


# The paper preset's VAE agent FMU, the largest archive rhi makes, holds about 70 MB: every bound is
# far above what a real FMU, package or checkpoint of this project needs, and far below a full disk.
LIMITS = Limits()
_CHUNK = 2**20


class ArchiveError(ComponentError):
    """An archive refused before anything was unpacked; the message names the archive, member and rule."""


def _kind(info: zipfile.ZipInfo) -> str | None:
    """What a member is by its Unix mode, when the archive records one: None for a file or folder."""
    mode = info.external_attr >> 16
    if not stat.S_IFMT(mode) or stat.S_ISREG(mode) or stat.S_ISDIR(mode):  # no type recorded: a file
        return None
    return {stat.S_IFLNK: "a symbolic link", stat.S_IFCHR: "a device", stat.S_IFBLK: "a device",
            stat.S_IFIFO: "a FIFO", stat.S_IFSOCK: "a socket"}.get(stat.S_IFMT(mode), "not an ordinary file")


def member_problem(name: str) -> str | None:
    """Why a member named ``name`` could land outside the folder it unpacks into (None: it cannot)."""
    if not name or name.startswith(("/", "\\")) or (len(name) > 1 and name[1] == ":"):
        return "is an absolute name"
    if "\\" in name or "\0" in name:
        return "holds a backslash or NUL"
    parts = name.rstrip("/").split("/")
    if any(part in ("", ".", "..") for part in parts):
        return "has an empty, '.' or '..' part"
    return None


def check_archive(path, limits: Limits = LIMITS) -> list[zipfile.ZipInfo]:
    """The members of the zip archive at ``path``, every one checked (see the module's docstring).

    Parameters
    ----------
    path : path
        The archive.
    limits : Limits
        The bounds.

    Returns
    -------
    list of ZipInfo
        Its members, in the archive's order.

    Raises
    ------
    ArchiveError
        One line naming the archive, the first member refused and why (or that it is not a zip archive).
    """
    label = os.path.basename(os.fspath(path))
    try:
        with zipfile.ZipFile(path) as archive:
            members = archive.infolist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, ValueError, EOFError) as error:
        raise ArchiveError(f"{label}: not a readable zip archive ({' '.join(str(error).split())[:160]})") from None
    if len(members) > limits.members:
        raise ArchiveError(f"{label}: {len(members)} members, over the limit of {limits.members}")
    seen, total = set(), 0
    for info in members:
        name = info.filename
        problem = member_problem(name) or (f"is {_kind(info)}" if _kind(info) else None)
        if problem is None and name.rstrip("/") in seen:
            problem = "appears twice"
        if problem is None and info.file_size > limits.member_bytes:
            problem = f"unpacks to {info.file_size} bytes, over the limit of {limits.member_bytes}"
        if (problem is None and info.file_size > limits.ratio_floor
                and info.file_size > limits.ratio * max(info.compress_size, 1)):
            problem = (f"unpacks {info.file_size / max(info.compress_size, 1):.0f} times its packed size, over "
                       f"the limit of {limits.ratio:g} (a zip bomb)")
        if problem is not None:
            raise ArchiveError(f"{label}: member {name[:200]!r} {problem}; the archive is refused")
        seen.add(name.rstrip("/"))
        total += info.file_size
        if total > limits.total_bytes:
            raise ArchiveError(f"{label}: unpacks to over {limits.total_bytes} bytes, the limit; the archive is "
                               "refused")
    return members


def extract(path, target, limits: Limits = LIMITS) -> Path:
    """Unpack the zip archive at ``path`` into the folder ``target`` (created, or existing and empty).

    Checked whole first (:func:`check_archive`); then no file is written through a link, and no member
    yields more bytes than it declared.

    Returns
    -------
    Path
        ``target``.
    """
    members = check_archive(path, limits)
    target = Path(target)
    target.mkdir(parents=True, exist_ok=True)
    if any(target.iterdir()):
        raise ArchiveError(f"cannot unpack {os.path.basename(os.fspath(path))} into {target}: it is not empty")
    root = target.resolve()
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
    with zipfile.ZipFile(path) as archive:
        for info in members:
            destination = root.joinpath(*PurePosixPath(info.filename).parts)
            if destination.parent.resolve() != destination.parent or root not in (destination, *destination.parents):
                raise ArchiveError(f"{os.path.basename(os.fspath(path))}: member {info.filename!r} leads outside "
                                   "the folder it unpacks into")
            if info.is_dir():
                destination.mkdir(parents=True, exist_ok=True)
                continue
            destination.parent.mkdir(parents=True, exist_ok=True)
            written = 0
            with archive.open(info) as source, os.fdopen(os.open(destination, flags, 0o644), "wb") as out:
                while chunk := source.read(_CHUNK):
                    written += len(chunk)
                    if written > info.file_size:
                        raise ArchiveError(f"{os.path.basename(os.fspath(path))}: member {info.filename!r} "
                                           "unpacks to more than it declares")
                    out.write(chunk)
            mode = info.external_attr >> 16
            if mode & 0o111:
                os.chmod(destination, 0o755)  # a binary the archive marks executable stays so
    return target


def pack(folder, out, limits: Limits = LIMITS) -> Path:
    """Write the zip archive ``out`` from the ordinary files under ``folder`` (names relative to it),
    refusing a link, a device or a size over ``limits`` by name. The caller makes ``out`` whole or absent."""
    folder = Path(folder)
    files, total = [], 0
    for path in sorted(folder.rglob("*")):
        relative = path.relative_to(folder).as_posix()
        if path.is_symlink() or not (path.is_file() or path.is_dir()):
            raise ArchiveError(f"{folder.name}: {relative!r} is not an ordinary file or folder; not packed")
        if path.is_file():
            size = path.stat().st_size
            total += size
            if size > limits.member_bytes or total > limits.total_bytes or len(files) >= limits.members:
                raise ArchiveError(f"{folder.name}: {relative!r} takes the archive over its limits; not packed")
            files.append((path, relative))
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as archive:
        for path, relative in files:
            archive.write(path, relative)
    return Path(out)
