"""The ``rhi`` command line. Each subcommand lives in its own function; errors of
the user's making print one line on stderr and exit with status 2."""
from __future__ import annotations

import argparse
import os
import sys

from components.component import ComponentError
from master.commands import experiment as experiment_command
from master.cosim import ConfigError, SimulationError

USER_ERRORS = (ConfigError, ComponentError)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rhi", description="A deep active inference model of the rubber-hand illusion, as a co-simulation.")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    train = commands.add_parser("train", help="train a visual decoder")
    train.add_argument("--decoder", choices=("conv", "vae"), required=True)
    train.add_argument("--config", metavar="FILE")
    train.add_argument("--out", metavar="CKPT", required=True)
    train.set_defaults(run=lambda args: __import__("master.commands.train", fromlist=["_"]).run_train(args))

    experiment = commands.add_parser("experiment", help="run the paper's rubber-hand protocol")
    experiment_command.add_arguments(experiment)
    experiment.set_defaults(run=experiment_command.run_experiment)

    export = commands.add_parser("export-body", help="export the body plant as an FMI 2.0 FMU")
    export.add_argument("--variant", metavar="NAME", help="native (default: the pymunk plant) or kinematic")
    export.add_argument("--out", metavar="FILE.fmu", required=True)
    export.set_defaults(run=lambda args: __import__("master.commands.export_body", fromlist=["_"]).run_export(args))

    sweep = commands.add_parser("sweep", help="run a parameter sweep, locally or on a Dask cluster")
    sweep.add_argument("--config", metavar="FILE", required=True, help="the sweep file (TOML, see README)")
    sweep.add_argument("--scheduler", metavar="ADDRESS",
                       help="a Dask scheduler, tcp://HOST:PORT (default: a process pool on this machine)")
    sweep.add_argument("--out", metavar="DIR", required=True)
    sweep.add_argument("--force", action="store_true", help="replace a different sweep in DIR")
    sweep.set_defaults(run=lambda args: __import__("master.commands.sweep", fromlist=["_"]).run_sweep(args))

    phenomenon = commands.add_parser("phenomenon", help="a human phenomenon (temporal window, distance, time "
                                                        "course): the model beside the human data")
    __import__("master.commands.phenomenon", fromlist=["_"]).add_arguments(phenomenon)
    phenomenon.set_defaults(
        run=lambda args: __import__("master.commands.phenomenon", fromlist=["_"]).run_phenomenon(args))

    bench = commands.add_parser("bench", help="measure speed")
    bench.add_argument("--json", action="store_true", help="print the results as JSON (for machines)")
    bench.add_argument("--quick", action="store_true", help="tiny settings: a smoke test in seconds")
    bench.add_argument("--threads", type=int, default=0, metavar="N",
                       help="torch threads (default: all cores; 1 on a machine busy with other work)")
    bench.add_argument("--checkpoint", metavar="CKPT", default="",
                       help="trained conv decoder for the fast mode's drift error (default: the cached default)")
    bench.set_defaults(run=lambda args: __import__("master.commands.bench", fromlist=["_"]).run_bench(args))
    return parser


def main(argv: list[str] | None = None) -> int:
    # Torch's OpenMP threads spin while they wait at barriers by default, which made training about
    # 10x slower on cores shared with other processes; passive waiting costs little on free cores.
    # OpenMP reads this once, when torch loads: here, before any command imports torch (this module
    # does not), and inherited by the processes a command starts.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    args = build_parser().parse_args(argv)
    try:
        return args.run(args) or 0
    except USER_ERRORS as error:
        if args.debug:
            raise
        print(f"rhi {args.command}: error: {error}", file=sys.stderr)
        return 2
    except SimulationError as error:
        if args.debug:
            raise
        print(f"rhi {args.command}: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"rhi {args.command}: interrupted (run the same command again to resume a sweep)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
