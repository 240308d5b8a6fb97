"""`rhi run-system FILE.ssp`: an SSP package run under FMPy's, libcosim's or Ecos's master; the CSV written, printed."""
from __future__ import annotations

import time

from rhi.master.commands.export_agent import check_out

HELP = "run an SSP package under FMPy's, libcosim's or Ecos's master"


def add_arguments(parser) -> None:
    """`rhi run-system`'s arguments."""
    parser.add_argument("ssp", metavar="FILE.ssp")
    parser.add_argument("--master", choices=("fmpy", "libcosim", "ecos"), default="libcosim")
    parser.add_argument("--trial", metavar="NAME", help="the agent's parameter file resources/trials/NAME.ssv "
                                                        "instead of the bound one (e.g. conv_right_sync_0, or "
                                                        "a reach's conv_near_1)")
    parser.add_argument("--steps", type=int, metavar="N", help="steps (default: the SSD's stop time)")
    parser.add_argument("--out", metavar="FILE.csv", required=True, help="every connector, one row per step")
    parser.add_argument("--force", action="store_true", help="replace an existing --out FILE, if rhi wrote it")


def run(args) -> int:
    """The ``rhi run-system`` command: args.ssp, .master, .trial, .steps, .out."""
    from rhi.master.export.system import final_drift_cm, final_goal_distance_cm, run_ssp, write_csv

    started = time.perf_counter()
    check_out(args, "CSV file", ".csv")
    values = run_ssp(args.ssp, args.master, args.trial, args.steps)
    write_csv(args.out, values)
    print(f"wrote {args.out} ({len(values['time'])} steps under {args.master}) in "
          f"{time.perf_counter() - started:.1f} s")
    if {"agent.goal_hand_x", "body.hand_x"} <= set(values):  # the reach
        print(f"final distance to the goal: {final_goal_distance_cm(values):.6f} cm")
    elif {"agent.mu_shoulder", "body.q_shoulder"} <= set(values):
        print(f"final drift: {final_drift_cm(values):.6f} cm")
    return 0
