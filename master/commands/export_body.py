"""`rhi export-body [--variant NAME] [--force] --out FILE.fmu`: arguments in, the written file printed."""
from __future__ import annotations

import os
import time

from master.export.body import export_body


def run_export(args) -> int:
    """The ``rhi export-body`` command: args.variant (None: native), args.out, args.force (replace an FMU rhi wrote)."""
    from master.commands.export_agent import check_out

    started = time.perf_counter()
    check_out(args, "FMU file", ".fmu")
    path = export_body(args.out, args.variant or "native")
    print(f"wrote {path} ({os.path.getsize(path) / 1024:.0f} KiB, variant {args.variant or 'native'}) "
          f"in {time.perf_counter() - started:.2f} s")
    return 0
