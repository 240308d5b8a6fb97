"""`rhi bench [--json] [--quick] [--threads N] [--checkpoint CKPT] [--training | --cohort]`: arguments in, the report printed."""
from __future__ import annotations

import json
import sys
from dataclasses import replace

from rhi.master.cosim import ConfigError
from rhi.master.config import MAX_THREADS, file_problem


HELP = "measure speed"


def add_arguments(parser) -> None:
    """`rhi bench`'s arguments."""
    parser.add_argument("--json", action="store_true", help="print the results as JSON (for machines)")
    parser.add_argument("--quick", action="store_true", help="tiny settings: a smoke test in seconds")
    parser.add_argument("--threads", type=int, default=0, metavar="N",
                        help="torch threads (default: all cores; 1 on a machine busy with other work)")
    parser.add_argument("--checkpoint", metavar="CKPT", default="",
                        help="trained conv decoder for the fast mode's drift error, at the default resolution "
                             "(default: the default conv decoder, the cache's, else the shipped one; --quick: an "
                             "untrained tiny one)")
    parser.add_argument("--cohort", action="store_true",
                        help="instead: CPU-µs per participant-step of every registered model at cohort batch sizes "
                             "(60, 300, 1200; --quick: 4, 12), each part's share, on the batched and the pymunk arm")
    parser.add_argument("--training", action="store_true",
                        help="instead: samples/s of the paper decoders' training step at 256x256, before and after "
                             "the paper preset's settings, phase by phase (--quick: tiny, 32x32)")


def run(args) -> int:
    """The ``rhi bench`` command: args.json, and optionally args.quick, args.threads."""
    from rhi.master.bench.report import table
    from rhi.master.bench.settings import QUICK, BenchSettings
    from rhi.master.bench.suite import run_suite

    settings = QUICK if getattr(args, "quick", False) else BenchSettings()
    threads = getattr(args, "threads", 0) or 0
    if not 0 <= threads <= MAX_THREADS:
        raise ConfigError(f"--threads {threads} must be 0 (all cores) to {MAX_THREADS} threads")
    checkpoint = getattr(args, "checkpoint", "") or ""
    problem = file_problem(checkpoint) if checkpoint else None
    if problem:
        raise ConfigError(f"--checkpoint {checkpoint} {problem}")
    if getattr(args, "cohort", False):
        if checkpoint or getattr(args, "training", False):
            raise ConfigError("--cohort measures the shipped decoders' cohorts: give neither --checkpoint nor --training")
        from rhi.master.bench.cohort import cohort_report, cohort_table
        return shown(args, cohort_report(quick=getattr(args, "quick", False)), cohort_table)
    if checkpoint and getattr(args, "training", False):
        raise ConfigError("--checkpoint names the decoder of the fast mode's drift error; --training measures the "
                          "training step, which uses none: give one or the other")
    if checkpoint:  # the drift error's decoder (--quick too), checked before anything is measured
        from rhi.master import config as configuration
        from rhi.master.decoders.cache import check_kind, loaded

        config = configuration.load()
        check_kind("conv", checkpoint, loaded(checkpoint, config["experiment"]["resolution"], config["camera"]["blur"]))
    if getattr(args, "training", False):
        from rhi.master.bench import training
        from rhi.master import config as configuration
        quick = getattr(args, "quick", False)
        report = training.training_rates(configuration.load(quick=quick, preset_name=None if quick else "paper"),
                                         steps=2 if quick else 3, threads=threads)
        return shown(args, report, training.table)
    settings = replace(settings, threads=threads, error_checkpoint=checkpoint,
                       **({"error_model": "cached"} if checkpoint else {}))  # --quick measures it on CKPT too
    return shown(args, run_suite(settings), table)


def shown(args, report: dict, table_of) -> int:
    """Print ``report`` on stdout: as JSON with ``--json``, else as ``table_of(report)``; exit status 0."""
    if getattr(args, "json", False):
        json.dump(report, sys.stdout, indent=1, default=float)
        print()
    else:
        print(table_of(report))
    return 0
