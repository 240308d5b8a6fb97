"""An output folder's manifest: every file rhi wrote there, with its size and sha256, so that rhi removes or
replaces only the files it can prove it wrote (docs/safety.md).

``.rhi-manifest.json`` in the folder::

    {"command": "rhi experiment", "folders": ["figures"],
     "files": {"summary.csv": {"bytes": 812, "sha256": "9f2c..."}, "figures/a_drift_final.png": {...}}}

A file is *proven* when the manifest lists it, it is still a regular file (not a link) and its bytes still
hash to what is listed; anything else under the folder (a file of the user's, one edited since rhi wrote it,
a link, a device) is not, and stays.
"""
from __future__ import annotations

import hashlib
import json
import os
import stat
from pathlib import Path, PurePosixPath

NAME = ".rhi-manifest.json"
IGNORED = (NAME, ".rhi-staging")  # not listed: the manifest itself, a staging folder's mark (files.STAGING_MARK)


def digest(path: Path) -> dict | None:
    """``{"bytes": size, "sha256": hex}`` of the regular file at ``path`` (never through a link); None if not one."""
    try:
        if not stat.S_ISREG(os.lstat(path).st_mode):
            return None
        hasher, size = hashlib.sha256(), 0
        with open(path, "rb") as file:
            for block in iter(lambda: file.read(1 << 20), b""):
                hasher.update(block)
                size += len(block)
    except OSError:
        return None
    return {"bytes": size, "sha256": hasher.hexdigest()}


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
        entry = digest(self.folder / relative)
        if entry is None:
            self.files.pop(relative, None)
            return
        self.files[relative] = entry
        parent = PurePosixPath(relative).parent
        while str(parent) != ".":
            self.folders.add(parent.as_posix())
            parent = parent.parent

    def proven(self, relative: str) -> bool:
        """Whether ``relative`` is a file rhi wrote, unchanged since."""
        return relative in self.files and digest(self.folder / relative) == self.files[relative]

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
                                 digest(Path(root) / name) is not None else path)
        return sorted(found)

    def remove_proven(self, keep=()) -> list[str]:
        """Remove every listed file that is proven (but those in ``keep``), then every listed folder left
        empty, deepest first; the rest stays. A listed file edited or gone since is no longer listed (it is
        not rhi's now). Returns what was removed."""
        removed = []
        for relative in sorted(self.files):
            if not self.proven(relative):
                del self.files[relative]
            elif relative not in keep:
                (self.folder / relative).unlink()
                del self.files[relative]
                removed.append(relative)
        for relative in sorted(self.folders, key=lambda name: -name.count("/")):
            path = self.folder / relative
            if path.is_dir() and not path.is_symlink() and not any(path.iterdir()):
                path.rmdir()
                self.folders.discard(relative)
                removed.append(relative + "/")
        return removed

    def save(self) -> None:
        """Write the manifest into the folder, atomically."""
        from master.outputs.files import atomic_write

        data = {"command": self.command, "folders": sorted(self.folders),
                "files": {name: self.files[name] for name in sorted(self.files)}}
        atomic_write(self.folder / NAME, json.dumps(data, indent=1) + "\n")
