"""The ``rhi`` command line: a table of commands (:data:`COMMANDS`), each a module of its own.

Exit status: 0 done; 2 refused (bad input: one line on stderr, nothing written); 1 a run that failed in
part or could not finish (a failed trial, a full disk, a closed stdout: one line each, what completed is
written); 130 interrupted by Ctrl-C (SIGINT), 143 by SIGTERM (nothing half-written is left).
"""
from __future__ import annotations

import argparse
import errno
import importlib
import os
import signal
import sys
import threading
from contextlib import nullcontext, redirect_stdout

from rhi.components.component import ComponentError
from rhi.master.runtime.interrupts import Terminated
from rhi.master.cosim import ConfigError, SimulationError
from rhi.master.cosim.errors import one_line
from rhi.master.runtime import contained

USER_ERRORS = (ConfigError, ComponentError)
STDOUT_ERRORS = (errno.EPIPE, errno.ENOSPC, errno.EBADF, errno.EIO)


class Parser(argparse.ArgumentParser):
    """argparse, with a usage error as one line (``rhi experiment: error: ...``) and exit status 2."""

    def error(self, message):
        """Exit with status 2 and the usage error as one line on stderr, pointing to ``--help``."""
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


_RECEIVED: list[int] = []  # the signals _interrupted turned into an exception in this run, not yet reported


def _interrupted(signum, frame):
    """SIGINT or SIGTERM: the run stops (KeyboardInterrupt, or Terminated) and cleans up. The signal's default
    action is restored first, never SIG_IGN: if the exception is swallowed where Python cannot pass it on (a
    garbage-collection callback: "Exception ignored ..."), the next signal still ends the process, and
    :func:`main` reports the interrupt when the run returns (exit status 130 or 143, not 0)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _RECEIVED.append(signum)
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("rhi")
    except metadata.PackageNotFoundError:  # run from a checkout that was never installed
        return "(not installed)"


# Every command: its name -> its module in master/commands, which defines HELP, add_arguments(parser) and run(args)
# (the exit status). A module imports only what parsing needs at its top; what running needs, in run().
COMMANDS = {"train": "train", "experiment": "experiment", "export-body": "export_body", "export-agent": "export_agent",
            "export-system": "export_system", "run-system": "run_system", "sweep": "sweep",
            "phenomenon": "phenomenon", "fit": "fit", "power": "power", "reach": "reach", "run": "run", "bench": "bench"}


def build_parser() -> argparse.ArgumentParser:
    """The ``rhi`` parser: the global options (``--debug``, ``-v``/``-q``, ``--version``) and each subcommand with
    its ``run``."""
    parser = Parser(
        prog="rhi", description="A deep active inference model of the rubber-hand illusion, as a co-simulation.")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    said = parser.add_mutually_exclusive_group()
    said.add_argument("-v", "--verbose", dest="verbosity", action="store_const", const=1, default=0,
                      help="also log the run's steps on stderr")
    said.add_argument("-q", "--quiet", dest="verbosity", action="store_const", const=-1,
                      help="print nothing but errors: no progress, notes, warnings or results")
    parser.add_argument("--version", action="version", version=f"rhi {_version()}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name in COMMANDS.items():
        module = importlib.import_module(f"rhi.master.commands.{module_name}")
        command = commands.add_parser(name, help=module.HELP)
        module.add_arguments(command)
        command.set_defaults(run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``rhi`` with ``argv`` (None: ``sys.argv[1:]``) and return its exit status (the module's: 0, 1, 2, 130, 143);
    a usage error exits with 2 from the parser."""
    # Torch's OpenMP threads spin while they wait at barriers by default, which made training about
    # 10x slower on cores shared with other processes; passive waiting costs little on free cores.
    # OpenMP reads this once, when torch loads: here, before any command imports torch (this module
    # does not), and inherited by the processes a command starts.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    stdout_closed = _standard_streams()
    args = build_parser().parse_args(argv)
    args.stdout_closed = stdout_closed
    args.argv = list(sys.argv[1:] if argv is None else argv)  # a command that runs itself in a child passes them on
    from rhi.components.fmu import watchdog

    main_thread = threading.current_thread() is threading.main_thread()
    handlers = {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM)} if main_thread else {}
    previous_stuck = watchdog.on_stuck
    for number in handlers:
        signal.signal(number, _interrupted)
    watchdog.on_stuck = _stuck_handler(args.command)
    status = None
    _RECEIVED.clear()
    from rhi.master.outputs.out_file import forget_checked

    forget_checked()
    try:
        status = _run(args)
        if _RECEIVED and status not in (130, 143):  # an interrupt swallowed on its way (_interrupted): said now
            status = _report_interrupt(args.command, _RECEIVED[-1] == signal.SIGTERM)
        contained.report_done(status)
        return status
    finally:
        watchdog.on_stuck = previous_stuck
        if status not in (130, 143):  # interrupted: a second Ctrl-C must not cut the exit's clean-up short
            for number, handler in handlers.items():
                signal.signal(number, signal.SIG_DFL if handler is None else handler)


def _run(args) -> int:
    from rhi.master.runtime.logs import configured

    with configured(args.verbosity), (open(os.devnull, "w") if args.verbosity < 0 else nullcontext()) as silent:
        with redirect_stdout(silent) if silent else nullcontext():
            return _run_logged(args)


def _run_logged(args) -> int:
    try:
        status = args.run(args) or 0
        if getattr(args, "stdout_closed", False):  # what it printed went nowhere: said, as a closed pipe is
            raise OSError(errno.EBADF, os.strerror(errno.EBADF))
        sys.stdout.flush()  # a full or closed stdout fails here, not silently at exit
        return status
    except USER_ERRORS as error:
        if args.debug:
            raise
        return _fail(args.command, error, 2)
    except SimulationError as error:
        if args.debug:
            raise
        return _fail(args.command, error, 1)
    except KeyboardInterrupt as interrupt:
        return _report_interrupt(args.command, isinstance(interrupt, Terminated))
    except MemoryError:
        if args.debug:
            raise
        return _fail(args.command, "out of memory (lower experiment.resolution, steps or trials)", 1)
    except OSError as error:  # the machine's, not the input's: a full disk, a closed stdout, a vanished folder
        if args.debug:
            raise
        return _fail(args.command, describe(error), 1)


def _report_interrupt(command: str, terminated: bool) -> int:
    """One line saying the run was interrupted; its exit status (143 for SIGTERM, 130 for Ctrl-C)."""
    name = "SIGTERM" if terminated else "Ctrl-C"
    resume = f" (run the same command again to resume the {command})" if command in ("sweep", "fit") else ""
    _fail(command, f"interrupted by {name}; nothing half-written is left{resume}", 0, "")
    return 143 if terminated else 130


def _standard_streams() -> bool:
    """Make the standard streams safe to use; whether standard output was closed.

    A closed descriptor 0, 1 or 2 is opened on /dev/null, so that no file rhi opens later takes its number (a
    library's print would land in it); sys.stdout (None then) writes there. Text that the streams' encoding
    cannot show (a non-ASCII --out under PYTHONIOENCODING=ascii) is escaped, never an error after the work."""
    closed = False
    for number in (0, 1, 2):
        try:
            os.fstat(number)
        except OSError:
            closed = closed or number == 1
            descriptor = os.open(os.devnull, os.O_RDWR)
            if descriptor != number:
                os.dup2(descriptor, number)
                os.close(descriptor)
    if sys.stdout is None:
        sys.stdout, closed = open(1, "w", closefd=False), True
    if sys.stderr is None:
        sys.stderr = open(2, "w", closefd=False)
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure"):
            try:
                stream.reconfigure(errors="backslashreplace")
            except (ValueError, OSError):
                pass
    return closed


def describe(error: OSError) -> str:
    """An OSError in words: ``cannot write to standard output (Broken pipe)``, ``/x/y: No space left on device``.

    Every file the program writes goes through atomic_write, which names it; an error of writing that names
    no file is standard output's (closed, or on a full device)."""
    reason = error.strerror or str(error) or type(error).__name__
    if error.filename is None and error.errno in STDOUT_ERRORS:
        return f"cannot write to standard output ({reason})"
    return f"{error.filename}: {reason}" if error.filename else reason


def _is_stdout_broken() -> bool:
    try:
        sys.stdout.flush()
        return False
    except (OSError, ValueError):
        return True


def _fail(command: str, message, status: int, prefix: str = "error: ") -> int:
    """One line on stderr; stdout pointed at /dev/null if it cannot be written (no second error at exit)."""
    if _is_stdout_broken():
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        except (OSError, ValueError):
            pass
    try:
        print(f"rhi {command}: {prefix}{one_line(message)}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass
    return status


def _stuck_handler(command: str):
    """An FMU stuck in native code past its time limit cannot be stopped in this process: the adapter's
    watchdog thread calls this, which removes this run's staging folder and lock and ends the process
    with status 1 and one line."""
    def stuck(message: str) -> None:
        from rhi.master.outputs.files import abandon_staging
        abandon_staging()
        try:
            sys.stderr.write("\n")  # after a progress bar's last line
        except (OSError, ValueError):
            pass
        _fail(command, message, 1)
        contained.report_done(1)
        os._exit(1)

    return stuck


if __name__ == "__main__":
    sys.exit(main())
