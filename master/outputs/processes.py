"""What a command leaves running when it ends: nothing. Its child processes die with it, even when it is
SIGKILLed (Linux's parent-death signal): `rhi run-system`'s master (master/export/ssp_runner.py) and the
local pool's Dask workers (master/sweeps/lifeline.py)."""
from __future__ import annotations

import os
import signal
import sys

PR_SET_PDEATHSIG = 1  # Linux's prctl option: the signal this process gets when its parent thread ends


def die_with_parent(parent: int | None = None) -> None:
    """Be killed when the parent dies, even by SIGKILL: Linux's PR_SET_PDEATHSIG (elsewhere: nothing). A
    parent gone already (this process adopted: its parent is no longer ``parent``, by default the parent
    now) ends this process now. The signal comes when the parent *thread* that started this process ends,
    so it suits children started from a thread that lives as long as they should."""
    import ctypes

    parent = os.getppid() if parent is None else parent
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent:
        os._exit(1)


def error_line(error: BaseException) -> str:
    """``Type: message``, the message on one line: how a child process reports a failure to its parent."""
    return f"{type(error).__name__}: {' '.join(str(error).split())}"


def exit_child(status: int):
    """End a child process now with ``status``, its streams flushed and nothing else run (no atexit, no
    finalizers: a master's native library may hang or crash in them)."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
