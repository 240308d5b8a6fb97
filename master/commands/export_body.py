"""`rhi export-body [--variant NAME] [--force] --out FILE.fmu`: arguments in, the written file printed."""
from __future__ import annotations

import os
import time

HELP = "export the body plant as an FMI 2.0 FMU"


def add_arguments(parser) -> None:
    """`rhi export-body`'s arguments."""
    parser.add_argument("--variant", metavar="NAME",
                        help="native (default: the pymunk plant), kinematic, or kinematic-c (the kinematic arm in C)")
    parser.add_argument("--out", metavar="FILE.fmu", required=True)
    parser.add_argument("--force", action="store_true", help="replace an existing --out FILE, if rhi wrote it")


def run(args) -> int:
    """The ``rhi export-body`` command: args.variant (None: native), args.out, args.force (replace an FMU rhi wrote)."""
    from master.commands.export_agent import check_out
    from master.export.body import export_body

    started = time.perf_counter()
    check_out(args, "FMU file", ".fmu")
    path = export_body(args.out, args.variant or "native")
    print(f"wrote {path} ({os.path.getsize(path) / 1024:.0f} KiB, variant {args.variant or 'native'}) "
          f"in {time.perf_counter() - started:.2f} s")
    return 0
