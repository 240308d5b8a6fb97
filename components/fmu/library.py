"""An FMU's files on this machine: unzipped once per process and file version, its shared library held
loaded, both released at exit."""
from __future__ import annotations

import atexit
import ctypes
import os
import shutil
import tempfile

from ..archives import extract
from .contract import library_path

# pythonfmu's export library (0.7) holds a global shared_ptr that C++ destroys at process exit and
# then resets again from its __attribute__((destructor)): a use-after-free that randomly aborts the
# process at exit ("corrupted double-linked list"). Calling the exported finalizePythonInterpreter
# from atexit, while the pointer is still alive, empties it, so both exit-time releases do nothing.
# We hold a handle on each such library (it cannot unload under us) and unzip each FMU once.
_GUARDED: dict[str, ctypes.CDLL] = {}
_EXTRACTED: dict[tuple, str] = {}


def guard_library(unzipdir: str, model_identifier: str) -> None:
    """Hold the FMU's shared library loaded and, if it is pythonfmu's, release its state at exit."""
    path = library_path(unzipdir, model_identifier)
    if path not in _GUARDED:
        library = ctypes.CDLL(path)
        _GUARDED[path] = library if hasattr(library, "finalizePythonInterpreter") else None


def extracted(path: str) -> str:
    """The FMU at ``path`` unzipped (checked: :func:`rhi.components.archives.extract`), once per process and
    file version (removed at exit)."""
    status = os.stat(path)
    key = (path, status.st_mtime_ns, status.st_size)
    if key not in _EXTRACTED:
        folder = tempfile.mkdtemp(prefix="rhi_fmu_")
        try:
            extract(path, folder)
        except BaseException:
            shutil.rmtree(folder, ignore_errors=True)
            raise
        _EXTRACTED[key] = folder
    return _EXTRACTED[key]


@atexit.register
def _release() -> None:
    for library in filter(None, _GUARDED.values()):
        library.finalizePythonInterpreter()
    for folder in _EXTRACTED.values():
        shutil.rmtree(folder, ignore_errors=True)
