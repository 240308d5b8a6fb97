"""`rhi run TASK [--model M] [--config FILE] [--quick] --out DIR`: any registered task, or one of one's own
(``path/to/file.py:Class``), into DIR: its tables, its figures and run.json (:mod:`rhi.master.tasks`)."""
from __future__ import annotations

import time
from pathlib import Path

from rhi.master.commands.experiment import add_device, add_model
from rhi.master.outputs.files import check_output

HELP = "run a task (a registered one, or FILE.py:Class of one's own) with a model into DIR"


def add_arguments(parser) -> None:
    """Add `rhi run`'s arguments to ``parser``."""
    parser.add_argument("task", metavar="TASK", help="a registered task (illusion, reach, moving-hand, reach-after, or "
                        "an entry point's name) or path/to/file.py:Class (examples/my_task.py)")
    add_model(parser)
    parser.add_argument("--config", metavar="FILE", help="a TOML file over the task's settings")
    parser.add_argument("--quick", action="store_true", help="the small fast settings (where the task has them)")
    parser.add_argument("--out", metavar="DIR", required=True)
    parser.add_argument("--force", action="store_true", help="replace DIR if it holds an earlier rhi output")
    add_device(parser)


def run(args) -> int:
    """Run `rhi run TASK` into ``args.out``; returns the exit status (0, or 1 when a trial failed and was left out)."""
    from rhi.master.tasks import get

    started = time.perf_counter()
    task = get(args.task)
    config = task.load(args.config, {}, args.quick, args.model)  # before torch loads: fast refusals
    check_output(args.out, args.force)
    from rhi.components.vision.component import resolve_device
    from rhi.master.runtime.context import RunContext
    from rhi.master.tasks import run_into

    result = run_into(task, args.out, config, RunContext.of(args, progress=True, device=resolve_device(args.device)))
    written = sorted(path.name for path in Path(args.out).iterdir() if not path.name.startswith("."))
    print(f"rhi run {args.task}: wrote {args.out}: {', '.join(written)} ({time.perf_counter() - started:.0f} s)")
    return 1 if result.failures else 0
