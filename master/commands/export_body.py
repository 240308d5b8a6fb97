"""`rhi export-body [--variant NAME] [--fmi VERSION] [--force] --out FILE.fmu`: arguments in, the written file printed."""
from __future__ import annotations

import os
import time

HELP = "export the body plant as an FMI 2.0 or FMI 3.0 FMU"


def add_arguments(parser) -> None:
    """`rhi export-body`'s arguments."""
    parser.add_argument("--variant", metavar="NAME",
                        help="native (default: the pymunk plant), kinematic, or kinematic-c (the kinematic arm in C)")
    parser.add_argument("--fmi", default="2.0", metavar="VERSION",
                        help="2.0 (default) or 3.0 (its ports as arrays)")
    parser.add_argument("--out", metavar="FILE.fmu", required=True)
    parser.add_argument("--force", action="store_true", help="replace an existing --out FILE, if rhi wrote it")


def run(args) -> int:
    """The ``rhi export-body`` command: args.variant (None: native), args.fmi (the FMI version), args.out,
    args.force (replace an FMU rhi wrote)."""
    from rhi.master.commands.export_agent import check_out
    from rhi.master.export.body import check_fmi, export_body

    started = time.perf_counter()
    variant, fmi = args.variant or "native", getattr(args, "fmi", "2.0")  # FMI 2.0 when a caller does not say
    check_fmi(variant, fmi)  # before --out is looked at: a refused version writes nothing
    check_out(args, "FMU file", ".fmu")
    path = export_body(args.out, variant, fmi)
    print(f"wrote {path} ({os.path.getsize(path) / 1024:.0f} KiB, variant {variant}, FMI {fmi}) "
          f"in {time.perf_counter() - started:.2f} s")
    return 0
