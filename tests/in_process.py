"""``rhi ARGS`` run in this process, as the command line would run it in a fresh one: the exit status, stdout and
stderr. For the refusals of tests/test_cli_catalogue.py and tests.faults.rhi, which need no process of their own: a
subprocess costs seconds of interpreter and imports a case, a call to main() milliseconds."""
from __future__ import annotations

import io
import os
import random
import signal
import sys
import tempfile
import threading
import traceback
import warnings
from dataclasses import dataclass
from pathlib import Path


@dataclass
class Done:
    status: int
    stdout: str
    stderr: str


def _show(message, category, filename, lineno, file=None, line=None):
    """A warning on stderr, as a fresh interpreter shows it (pytest would otherwise collect it)."""
    sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


def _fresh_interpreter_filters() -> None:
    """Python's default warning filters (those of ``python -m rhi``, not the test session's)."""
    warnings.resetwarnings()
    for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
        warnings.simplefilter("ignore", category)
    warnings.filterwarnings("default", category=DeprecationWarning, module="__main__")


class Overran(BaseException):
    """The call ran past its time limit (a BaseException: no except Exception in rhi takes it for its own)."""


def _overran(signum, frame):
    raise Overran("rhi ran past the test's time limit")


def rhi_in_process(args: list[str], cwd: Path, environment: dict[str, str], timeout: float | None = None) -> Done:
    """``rhi ARGS`` via rhi.master.commands.cli.main in ``cwd`` with ``environment`` added to os.environ; this process's
    working folder, environment, standard streams, warning filters, torch thread count, tempfile's folder, signal
    handlers and mask, and the random generators' states are restored after (a run seeds torch's: the tests after it
    must not see that). An exception that escapes main() is the traceback a fresh interpreter would print, with
    status 1; so is a run past ``timeout`` seconds (in the main thread: SIGALRM), as a hang would be a subprocess's."""
    import numpy
    import torch

    from rhi.master.commands.cli import main

    saved_environment, saved_cwd = dict(os.environ), os.getcwd()
    saved_streams = sys.stdout, sys.stderr
    threads = torch.get_num_threads()
    generators = torch.get_rng_state(), numpy.random.get_state(), random.getstate()
    saved_tempdir = tempfile.tempdir
    main_thread = threading.current_thread() is threading.main_thread()
    numbers = (signal.SIGINT, signal.SIGTERM, signal.SIGALRM) if main_thread else ()
    handlers = {number: signal.getsignal(number) for number in numbers}
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    out, err = io.StringIO(), io.StringIO()
    try:
        os.environ.update(environment)
        os.chdir(cwd)
        tempfile.tempdir = None  # tempfile caches its folder at first use: read $TMPDIR afresh, as a new process does
        sys.stdout, sys.stderr = out, err
        if main_thread and timeout:
            signal.signal(signal.SIGALRM, _overran)
            signal.setitimer(signal.ITIMER_REAL, timeout)
        with warnings.catch_warnings():
            _fresh_interpreter_filters()
            warnings.showwarning = _show
            try:
                status = main(list(args))
            except SystemExit as exit:  # argparse's usage errors, as the interpreter turns them into a status
                code = exit.code
                if code is not None and not isinstance(code, int):
                    print(code, file=sys.stderr)
                status = 1 if code is not None and not isinstance(code, int) else code or 0
            except BaseException:  # what the interpreter would print for an exception no one caught
                traceback.print_exc(file=sys.stderr)
                status = 1
    finally:
        if main_thread and timeout:
            signal.setitimer(signal.ITIMER_REAL, 0)
        for number, handler in handlers.items():
            signal.signal(number, signal.SIG_DFL if handler is None else handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        sys.stdout, sys.stderr = saved_streams
        os.chdir(saved_cwd)
        tempfile.tempdir = saved_tempdir
        os.environ.clear()
        os.environ.update(saved_environment)
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)
        torch.set_rng_state(generators[0])
        numpy.random.set_state(generators[1])
        random.setstate(generators[2])
    return Done(status, out.getvalue(), err.getvalue())
