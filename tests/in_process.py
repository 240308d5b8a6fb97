"""``rhi ARGS`` run in this process, as the command line would run it in a fresh one: the exit status, stdout and
stderr. For the refusals of tests/test_cli_catalogue.py, which need no process of their own: a subprocess costs
seconds of interpreter and imports a case, a call to main() milliseconds."""
from __future__ import annotations

import io
import os
import sys
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
    """Python's default warning filters (those of ``python -m master``, not the test session's)."""
    warnings.resetwarnings()
    for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
        warnings.simplefilter("ignore", category)
    warnings.filterwarnings("default", category=DeprecationWarning, module="__main__")


def rhi_in_process(args: list[str], cwd: Path, environment: dict[str, str]) -> Done:
    """``rhi ARGS`` via master.commands.cli.main in ``cwd`` with ``environment`` added to os.environ; this process's
    working folder, environment, standard streams, warning filters and torch thread count are restored after.
    An exception that escapes main() is the traceback a fresh interpreter would print, with status 1."""
    import torch

    from master.commands.cli import main

    saved_environment, saved_cwd = dict(os.environ), os.getcwd()
    saved_streams = sys.stdout, sys.stderr
    threads = torch.get_num_threads()
    out, err = io.StringIO(), io.StringIO()
    try:
        os.environ.update(environment)
        os.chdir(cwd)
        sys.stdout, sys.stderr = out, err
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
        sys.stdout, sys.stderr = saved_streams
        os.chdir(saved_cwd)
        os.environ.clear()
        os.environ.update(saved_environment)
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)
    return Done(status, out.getvalue(), err.getvalue())
