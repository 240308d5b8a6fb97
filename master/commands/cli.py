"""The ``rhi`` command line. Each subcommand lives in its own function.

Exit status: 0 done; 2 refused (bad input: one line on stderr, nothing written); 1 a run that failed in
part or could not finish (a failed trial, a full disk, a closed stdout: one line each, what completed is
written); 130 interrupted by Ctrl-C (SIGINT), 143 by SIGTERM (nothing half-written is left).
"""
from __future__ import annotations

import argparse
import errno
import os
import signal
import sys
import threading

from components.component import ComponentError
from master.commands import experiment as experiment_command
from master.cosim import ConfigError, SimulationError
from master.cosim.errors import one_line

USER_ERRORS = (ConfigError, ComponentError)
STDOUT_ERRORS = (errno.EPIPE, errno.ENOSPC, errno.EBADF, errno.EIO)


class Parser(argparse.ArgumentParser):
    """argparse, with a usage error as one line (``rhi experiment: error: ...``) and exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: the same clean-up, exit status 143."""


def _interrupted(signum, frame):
    """SIGINT or SIGTERM: the run stops (KeyboardInterrupt, or Terminated) and cleans up; a second one while
    it cleans up is ignored, so that the clean-up and the exit are not cut short."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("rhi")
    except metadata.PackageNotFoundError:  # run from a checkout that was never installed
        return "(not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="rhi", description="A deep active inference model of the rubber-hand illusion, as a co-simulation.")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    parser.add_argument("--version", action="version", version=f"rhi {_version()}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    train = commands.add_parser("train", help="train a visual decoder")
    train.add_argument("--decoder", choices=("conv", "vae"), required=True)
    train.add_argument("--config", metavar="FILE")
    experiment_command.add_preset(train)
    experiment_command.add_device(train)
    train.add_argument("--out", metavar="CKPT", required=True)
    train.set_defaults(run=lambda args: __import__("master.commands.train", fromlist=["_"]).run_train(args))

    experiment = commands.add_parser("experiment", help="run the paper's rubber-hand protocol")
    experiment_command.add_arguments(experiment)
    experiment.set_defaults(run=experiment_command.run_experiment)

    export = commands.add_parser("export-body", help="export the body plant as an FMI 2.0 FMU")
    export.add_argument("--variant", metavar="NAME",
                        help="native (default: the pymunk plant), kinematic, or kinematic-c (the kinematic arm in C)")
    export.add_argument("--out", metavar="FILE.fmu", required=True)
    export.add_argument("--force", action="store_true", help="replace an existing --out FILE, if rhi wrote it")
    export.set_defaults(run=lambda args: __import__("master.commands.export_body", fromlist=["_"]).run_export(args))

    module = "master.commands.export_agent"
    agent = commands.add_parser("export-agent", help="export the agent (stimulus, rubber arm, camera, decoder, brain; "
                                                     "--task reach: the reach's) as an FMI 2.0 FMU")
    __import__(module, fromlist=["_"]).add_common(agent)
    agent.add_argument("--out", metavar="FILE.fmu", required=True)
    agent.set_defaults(run=lambda args: __import__(module, fromlist=["_"]).run_export_agent(args))

    system = commands.add_parser("export-system", help="export the experiment as an SSP 1.0 package (agent and "
                                                       "body FMUs, a parameter file per trial)")
    __import__(module, fromlist=["_"]).add_common(system)
    system.add_argument("--body-variant", metavar="NAME",
                        help="the body to export with it: native (default, the pymunk plant), kinematic, kinematic-c")
    system.add_argument("--body", metavar="FMU", help="a body FMU of one's own (the body contract) instead")
    system.add_argument("--trial", metavar="C/S/I", help="the trial the SSD binds, CONDITION/STIMULATION/INDEX "
                                                        "(default: the protocol's first, e.g. left/sync/0; --task "
                                                        "reach: BAND/INDEX, default the plan's first, e.g. near/0)")
    system.add_argument("--out", metavar="FILE.ssp", required=True)
    system.set_defaults(run=lambda args: __import__(module, fromlist=["_"]).run_export_system(args))

    run_system = commands.add_parser("run-system", help="run an SSP package under FMPy's or libcosim's master")
    run_system.add_argument("ssp", metavar="FILE.ssp")
    run_system.add_argument("--master", choices=("fmpy", "libcosim"), default="libcosim")
    run_system.add_argument("--trial", metavar="NAME", help="the agent's parameter file resources/trials/NAME.ssv "
                                                            "instead of the bound one (e.g. conv_right_sync_0, or "
                                                            "a reach's conv_near_1)")
    run_system.add_argument("--steps", type=int, metavar="N", help="steps (default: the SSD's stop time)")
    run_system.add_argument("--out", metavar="FILE.csv", required=True, help="every connector, one row per step")
    run_system.add_argument("--force", action="store_true", help="replace an existing --out FILE, if rhi wrote it")
    run_system.set_defaults(run=lambda args: __import__(module, fromlist=["_"]).run_run_system(args))

    sweep = commands.add_parser("sweep", help="run a parameter sweep, locally or on a Dask cluster")
    sweep.add_argument("--config", metavar="FILE", required=True, help="the sweep file (TOML, see docs/sweeps.md)")
    sweep.add_argument("--scheduler", metavar="ADDRESS",
                       help="a Dask scheduler, tcp://HOST:PORT (default: a process pool on this machine)")
    sweep.add_argument("--out", metavar="DIR", required=True)
    sweep.add_argument("--force", action="store_true", help="replace a different sweep in DIR")
    sweep.add_argument("--model", metavar="NAME",
                       help="the model, instead of the sweep file's sweep.model (default there: paper; a name or "
                            "FILE.py:Class, docs/model.md)")
    sweep.set_defaults(run=lambda args: __import__("master.commands.sweep", fromlist=["_"]).run_sweep(args))

    phenomenon = commands.add_parser("phenomenon", help="a human phenomenon (temporal window, distance, time "
                                                        "course): the model beside the human data")
    __import__("master.commands.phenomenon", fromlist=["_"]).add_arguments(phenomenon)
    phenomenon.set_defaults(
        run=lambda args: __import__("master.commands.phenomenon", fromlist=["_"]).run_phenomenon(args))

    fit = commands.add_parser("fit", help="fit the model to participants' data by simulation-based inference, "
                                          "calibrated on held-out simulations")
    __import__("master.commands.fit", fromlist=["_"]).add_arguments(fit)
    fit.set_defaults(run=lambda args: __import__("master.commands.fit", fromlist=["_"]).run_fit(args))

    reach = commands.add_parser("reach", help="the free arm reaching to a seen goal: near and far goals per decoder")
    __import__("master.commands.reach", fromlist=["_"]).add_arguments(reach)
    reach.set_defaults(run=lambda args: __import__("master.commands.reach", fromlist=["_"]).run_reach(args))

    bench = commands.add_parser("bench", help="measure speed")
    bench.add_argument("--json", action="store_true", help="print the results as JSON (for machines)")
    bench.add_argument("--quick", action="store_true", help="tiny settings: a smoke test in seconds")
    bench.add_argument("--threads", type=int, default=0, metavar="N",
                       help="torch threads (default: all cores; 1 on a machine busy with other work)")
    bench.add_argument("--checkpoint", metavar="CKPT", default="",
                       help="trained conv decoder for the fast mode's drift error, at the default resolution "
                            "(default: the cached default; --quick: an untrained tiny one)")
    bench.add_argument("--training", action="store_true",
                       help="instead: samples/s of the paper decoders' training step at 256x256, before and after "
                            "the paper preset's settings, phase by phase (--quick: tiny, 32x32)")
    bench.set_defaults(run=lambda args: __import__("master.commands.bench", fromlist=["_"]).run_bench(args))
    return parser


def main(argv: list[str] | None = None) -> int:
    # Torch's OpenMP threads spin while they wait at barriers by default, which made training about
    # 10x slower on cores shared with other processes; passive waiting costs little on free cores.
    # OpenMP reads this once, when torch loads: here, before any command imports torch (this module
    # does not), and inherited by the processes a command starts.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    args = build_parser().parse_args(argv)
    from components.fmu import watchdog

    main_thread = threading.current_thread() is threading.main_thread()
    handlers = {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM)} if main_thread else {}
    previous_stuck = watchdog.on_stuck
    for number in handlers:
        signal.signal(number, _interrupted)
    watchdog.on_stuck = _stuck_handler(args.command)
    status = None
    try:
        status = _run(args)
        return status
    finally:
        watchdog.on_stuck = previous_stuck
        if status not in (130, 143):  # interrupted: a second Ctrl-C must not cut the exit's clean-up short
            for number, handler in handlers.items():
                signal.signal(number, signal.SIG_DFL if handler is None else handler)


def _run(args) -> int:
    try:
        status = args.run(args) or 0
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
        name = "SIGTERM" if isinstance(interrupt, Terminated) else "Ctrl-C"
        _fail(args.command, f"interrupted by {name}; nothing half-written is left"
                            f"{' (run the same command again to resume the ' + args.command + ')' if args.command in ('sweep', 'fit') else ''}",
              0, "")
        return 143 if isinstance(interrupt, Terminated) else 130
    except MemoryError:
        if args.debug:
            raise
        return _fail(args.command, "out of memory (lower experiment.resolution, steps or trials)", 1)
    except OSError as error:  # the machine's, not the input's: a full disk, a closed stdout, a vanished folder
        if args.debug:
            raise
        return _fail(args.command, describe(error), 1)


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
        from master.outputs.files import abandon_staging
        abandon_staging()
        try:
            sys.stderr.write("\n")  # after a progress bar's last line
        except (OSError, ValueError):
            pass
        _fail(command, message, 1)
        os._exit(1)

    return stuck


if __name__ == "__main__":
    sys.exit(main())
