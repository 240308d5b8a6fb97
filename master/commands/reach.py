"""`rhi reach`: the free arm reaching to a seen goal, near and far goals per decoder (docs/reach.md)."""
from __future__ import annotations

import logging
import time
from pathlib import Path

from rhi.master.commands.experiment import add_model
from rhi.master.outputs.files import check_output


HELP = "the free arm reaching to a seen goal: near and far goals per decoder"
log = logging.getLogger("rhi.reach")


def add_arguments(parser) -> None:
    """Add `rhi reach`'s arguments to ``parser``."""
    parser.add_argument("--config", metavar="FILE", help="TOML file overriding master/config/defaults.toml and "
                                                         "master/tasks/reach/reach.toml (reach.goals, reach.ranges, ...)")
    add_model(parser)
    parser.add_argument("--quick", action="store_true", help="a small version, for smoke tests (tiny decoders "
                                                             "at 32 px, 2 near goals, 500 steps)")
    parser.add_argument("--goals", type=int, help="goals per band (default 40)")
    parser.add_argument("--seed", type=int, help="master seed (draws the goals)")
    parser.add_argument("--out", metavar="DIR", required=True)
    parser.add_argument("--force", action="store_true", help="replace DIR if it holds an earlier rhi output")


def run(args) -> int:
    """Run `rhi reach` into ``args.out``; returns the exit status (0, or 1 when a reach failed and was left out)."""
    from rhi.master.tasks import TASKS, run_into

    started, task = time.perf_counter(), TASKS["reach"]
    overrides = {key: value for key, value in (("reach.goals", args.goals), ("experiment.seed", args.seed))
                 if value is not None}
    config = task.load(args.config, overrides, args.quick, args.model)
    check_output(args.out, args.force)
    from rhi.master.runtime.context import RunContext

    failures = run_into(task, args.out, config, RunContext.of(args, progress=True)).failures
    for trial, error in failures.items():
        log.error(f"rhi reach: reach failed and left out: {trial.decoder}/{trial.band} goal {trial.index}: {error}")
    print(f"wrote {args.out}: summary.csv, goals.csv, trials.csv, run.json, figures/ "
          f"({time.perf_counter() - started:.0f} s)")
    print((Path(args.out) / "summary.csv").read_text(), end="")
    return 1 if failures else 0
