"""`rhi export-system`: the experiment (or the reach) as an SSP 1.0 package; the written file printed."""
from __future__ import annotations

import os
import time

from rhi.master.commands.export_agent import add_common, check_out, load

HELP = "export the experiment as an SSP 1.0 package (agent and body FMUs, a parameter file per trial)"


def add_arguments(parser) -> None:
    """`rhi export-system`'s arguments: export-agent's, and the body and the bound trial."""
    add_common(parser)
    parser.add_argument("--body-variant", metavar="NAME",
                        help="the body to export with it: native (default, the pymunk plant), kinematic, kinematic-c")
    parser.add_argument("--body", metavar="FMU", help="a body FMU of one's own (the body contract) instead")
    parser.add_argument("--trial", metavar="C/S/I", help="the trial the SSD binds, CONDITION/STIMULATION/INDEX "
                                                        "(default: the protocol's first, e.g. left/sync/0; --task "
                                                        "reach: BAND/INDEX, default the plan's first, e.g. near/0)")
    parser.add_argument("--out", metavar="FILE.ssp", required=True)


def run(args) -> int:
    """The ``rhi export-system`` command: as export-agent, and .body_variant, .body, .trial."""
    from rhi.master.export.system import export_system

    started = time.perf_counter()
    check_out(args, "SSP file", ".ssp")
    path = export_system(args.out, load(args), args.decoder, args.body_variant or "native", args.body, args.trial,
                         args.task)
    print(f"wrote {path} ({os.path.getsize(path) / 1024:.0f} KiB: SystemStructure.ssd, the agent and body FMUs, a "
          f"parameter file per trial) in {time.perf_counter() - started:.1f} s")
    return 0
