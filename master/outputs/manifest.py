"""An output folder's manifest: every file rhi wrote there, with its size and sha256, so that rhi removes or
replaces only the files it can prove it wrote (docs/safety.md).

``.rhi-manifest.json`` in the folder::

    {"command": "rhi experiment", "folders": ["figures"],
     "files": {"summary.csv": {"bytes": 812, "sha256": "9f2c..."}, "figures/a_drift_final.png": {...}}}

A file is *proven* when the manifest lists it, it is still a regular file (not a link), the way to it from
the folder passes through folders only (no link: each part is opened relative to the one before with
O_NOFOLLOW) and its bytes still hash to what is listed; anything else under the folder (a file of the user's,
one edited since rhi wrote it, a link, a device, a file reached through a link to somewhere else) is not, and
stays. A proven file is removed, and a listed folder left empty, relative to the descriptor of the folder it
was proven in, never by a path that could be resolved again through a link.
"""
from __future__ import annotations

import hashlib
import json
import os
import stat
from pathlib import Path, PurePosixPath

from rhi.master.outputs.atomic import atomic_write

NAME = ".rhi-manifest.json"
IGNORED = (NAME, ".rhi-staging")  # not listed: the manifest itself, a staging folder's mark (files.STAGING_MARK)


FOLDER_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)
FILE_FLAGS = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)  # a FIFO opens, never waits


def open_parent(folder: str | os.PathLike, relative: str) -> tuple[int, str] | None:
    """(a descriptor of the folder that holds ``relative`` under ``folder``, the entry's name), every part of
    the way opened relative to the one before with O_NOFOLLOW; None if ``relative`` is not a safe relative name
    or a part of the way is not a folder (a link, a file, missing). The caller closes the descriptor."""
    if not safe_relative(relative):
        return None
    *way, name = relative.split("/")
    try:
        handle = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return None
    for part in way:
        try:
            inner = os.open(part, FOLDER_FLAGS, dir_fd=handle)
        except OSError:  # ELOOP, ENOTDIR: a link or a file where a folder belongs; ENOENT
            os.close(handle)
            return None
        os.close(handle)
        handle = inner
    return handle, name


def digest_at(handle: int, name: str) -> dict | None:
    """``{"bytes": size, "sha256": hex}`` of the regular file ``name`` in the open folder ``handle`` (never
    through a link); None if not one."""
    try:
        descriptor = os.open(name, FILE_FLAGS, dir_fd=handle)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            return None
        hasher, size = hashlib.sha256(), 0
        for block in iter(lambda: os.read(descriptor, 1 << 20), b""):
            hasher.update(block)
            size += len(block)
    except OSError:
        return None
    finally:
        os.close(descriptor)
    return {"bytes": size, "sha256": hasher.hexdigest()}


def digest(relative: str, folder: str | os.PathLike) -> dict | None:
    """``{"bytes": size, "sha256": hex}`` of the regular file ``relative`` under ``folder``, reached through
    folders only (:func:`open_parent`: no part of the way a link, nor the file itself); None if not one."""
    opened = open_parent(folder, relative)
    if opened is None:
        return None
    handle, name = opened
    try:
        return digest_at(handle, name)
    finally:
        os.close(handle)


def safe_relative(name) -> bool:
    """Whether ``name`` is a relative path inside the folder: no absolute part, no ``..``, no backslash."""
    if not isinstance(name, str) or not name or "\\" in name or "\0" in name:
        return False
    path = PurePosixPath(name)
    return not path.is_absolute() and all(part not in ("", ".", "..") for part in name.split("/"))


class Manifest:
    """The files and folders rhi wrote under ``folder`` for ``command``."""

    def __init__(self, folder: str | os.PathLike, command: str, files: dict | None = None,
                 folders: set | None = None):
        self.folder, self.command = Path(folder), command
        self.files: dict[str, dict] = dict(files or {})
        self.folders: set[str] = set(folders or ())

    @classmethod
    def read(cls, folder: str | os.PathLike, command: str | tuple[str, ...]) -> "Manifest | None":
        """The manifest in ``folder`` as rhi wrote it for ``command`` (or one of several); None if absent,
        damaged or another's."""
        path = Path(folder) / NAME
        try:
            if path.is_symlink():
                return None
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError):
            return None
        if not isinstance(data, dict) or data.get("command") not in ((command,) if isinstance(command, str) else command):
            return None
        files, folders = data.get("files"), data.get("folders")
        if not isinstance(files, dict) or not isinstance(folders, list):
            return None
        entries_ok = all(safe_relative(name) and isinstance(entry, dict) and isinstance(entry.get("sha256"), str)
                         and isinstance(entry.get("bytes"), int) for name, entry in files.items())
        if not entries_ok or not all(safe_relative(name) for name in folders):
            return None
        return cls(folder, data["command"], files, set(folders))

    @classmethod
    def of(cls, folder: str | os.PathLike, command: str) -> "Manifest":
        """A manifest of everything under ``folder`` now (a staging folder rhi has just filled)."""
        manifest = cls(folder, command)
        for root, folders, names in os.walk(folder):
            relative = Path(root).relative_to(folder)
            for name in folders:
                manifest.folders.add((relative / name).as_posix())
            for name in names:
                if relative != Path(".") or name not in IGNORED:
                    manifest.add((relative / name).as_posix())
        return manifest

    def add(self, relative: str) -> None:
        """List the file ``relative`` as it is now (rhi has just written it), and the folders above it."""
        entry = digest(relative, self.folder)
        if entry is None:
            self.files.pop(relative, None)
            return
        self.files[relative] = entry
        parent = PurePosixPath(relative).parent
        while str(parent) != ".":
            self.folders.add(parent.as_posix())
            parent = parent.parent

    def proven(self, relative: str) -> bool:
        """Whether ``relative`` is a file rhi wrote, unchanged since, reached from the folder through folders
        only (module notes)."""
        return relative in self.files and digest(relative, self.folder) == self.files[relative]

    def unproven(self) -> list[str]:
        """Every entry under the folder that is not rhi's as listed, sorted; a changed file says so."""
        found = []
        for root, folders, names in os.walk(self.folder):
            relative = Path(root).relative_to(self.folder)
            for name in sorted(folders):
                path = (relative / name).as_posix()
                if (Path(root) / name).is_symlink() or path not in self.folders:
                    found.append(path)
                    folders.remove(name)  # not descended: all of it is not ours
            for name in sorted(names):
                path = (relative / name).as_posix()
                if relative == Path(".") and name == NAME:
                    continue
                if not self.proven(path):
                    found.append(f"{path} (changed since rhi wrote it)" if path in self.files and
                                 digest(path, self.folder) is not None else path)
        return sorted(found)

    def remove_proven(self, keep=()) -> list[str]:
        """Remove every listed file that is proven (but those in ``keep``), then every listed folder left
        empty, deepest first; the rest stays. A listed file edited or gone since is no longer listed (it is
        not rhi's now). Returns what was removed."""
        removed = []
        for relative in sorted(self.files):
            opened = open_parent(self.folder, relative)
            if opened is None:  # not reached through folders of DIR's own: not rhi's
                del self.files[relative]
                continue
            handle, name = opened
            try:  # proven and removed in the same folder, held open: a link swapped in meanwhile is not followed
                if digest_at(handle, name) != self.files[relative]:
                    del self.files[relative]
                elif relative not in keep:
                    os.unlink(name, dir_fd=handle)
                    del self.files[relative]
                    removed.append(relative)
            finally:
                os.close(handle)
        for relative in sorted(self.folders, key=lambda name: -name.count("/")):
            opened = open_parent(self.folder, relative)
            if opened is None:  # not a folder of DIR's own (reached through a link, or gone): not listed
                self.folders.discard(relative)
                continue
            handle, name = opened
            try:
                if not stat.S_ISDIR(os.stat(name, dir_fd=handle, follow_symlinks=False).st_mode):
                    self.folders.discard(relative)  # a link or a file where rhi's folder was: not rhi's now
                    continue
                os.rmdir(name, dir_fd=handle)  # an empty folder only
            except OSError:  # not empty: it stays, listed; gone: not listed
                if not os.path.lexists(self.folder / relative):
                    self.folders.discard(relative)
                continue
            finally:
                os.close(handle)
            self.folders.discard(relative)
            removed.append(relative + "/")
        return removed

    def save(self) -> None:
        """Write the manifest into the folder, atomically."""
        data = {"command": self.command, "folders": sorted(self.folders),
                "files": {name: self.files[name] for name in sorted(self.files)}}
        atomic_write(self.folder / NAME, json.dumps(data, indent=1) + "\n")
