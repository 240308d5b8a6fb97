"""`rhi export-agent`: arguments in, the written file printed; the options and checks export-system and run-system
share with it.

An existing --out FILE is replaced only with --force, and only if rhi wrote it (:func:`check_out`)."""
from __future__ import annotations

import os
import time


HELP = ("export the agent (stimulus, rubber arm, camera, decoder, brain; --task reach: the reach's) as an FMI 2.0 FMU "
        "(--fmi 3.0: the illusion's, its camera image an array)")


def add_arguments(parser) -> None:
    """`rhi export-agent`'s arguments."""
    add_common(parser)
    parser.add_argument("--fmi", default="2.0", metavar="VERSION",
                        help="2.0 (default; pythonfmu) or 3.0 (pythonfmu3: the illusion's agent, its camera image a "
                             "Float64 array output)")
    parser.add_argument("--out", metavar="FILE.fmu", required=True)


def add_common(parser) -> None:
    """The options export-agent and export-system share: the task, the configuration and the decoder."""
    parser.add_argument("--task", default="illusion",
                        help="illusion (default: the experiment's agent) or reach (the free arm reaching to a seen "
                             "goal, docs/reach.md; its configuration is rhi reach's)")
    parser.add_argument("--config", metavar="FILE", help="TOML file overriding master/config/defaults.toml (and, for "
                                                         "--task reach, master/tasks/reach/reach.toml)")
    parser.add_argument("--quick", action="store_true", help="the --quick settings (a 32 px tiny decoder)")
    parser.add_argument("--model", default="paper", metavar="NAME",
                        help="the model whose brain the agent carries (default: paper; a name or FILE.py:Class whose "
                             "brain reads no pose encoder, docs/model.md)")
    parser.add_argument("--decoder", metavar="KIND", help="conv or vae (default: the configuration's first)")
    parser.add_argument("--checkpoint", metavar="CKPT", help="a trained decoder of that kind (default: the "
                                                             "configured one, or the cached default, trained if missing)")
    parser.add_argument("--force", action="store_true", help="replace an existing --out FILE, if rhi wrote it")


def check_out(args, noun: str, suffix: str) -> None:
    """--out FILE checked before any work: an existing file is replaced only with --force, and only if rhi wrote
    it, a file of its kind (rhi.master.export.own_files)."""
    from rhi.master.export import own_files
    from rhi.master.outputs.out_file import check_output_file, guard_out_file

    ours = {".fmu": own_files.fmu_problem, ".ssp": own_files.ssp_problem, ".csv": own_files.csv_problem}[suffix]
    check_output_file(args.out, noun, suffix, getattr(args, "force", False), ours)
    guard_out_file(args.out)  # what is there now: the finished file is never put over a file that appeared since


def load(args) -> dict:
    """The task's configuration: defaults (and master/tasks/reach/reach.toml for the reach), --quick, --config, and
    --checkpoint for the --decoder it belongs to."""
    from rhi.master.cosim import ConfigError
    from rhi.master.tasks import exportable as task

    if args.checkpoint and not args.decoder:
        raise ConfigError("--checkpoint needs --decoder (conv or vae): the kind of decoder it holds")
    overrides = {f"decoder.{args.decoder}_checkpoint": args.checkpoint} if args.checkpoint else {}
    if args.decoder not in (None, "conv", "vae"):
        raise ConfigError(f"--decoder {args.decoder!r} is not one of conv, vae")
    return task(args.task).load(args.config, overrides, args.quick, getattr(args, "model", "paper"))


def run(args) -> int:
    """The ``rhi export-agent`` command: args.out, .config, .quick, .decoder, .checkpoint."""
    from rhi.master.export.agent_fmu import export_agent

    started = time.perf_counter()
    from rhi.master.export.agent_fmu import check_fmi

    check_fmi(args.fmi, args.task)
    check_out(args, "FMU file", ".fmu")
    path, checkpoint = export_agent(args.out, load(args), args.decoder, args.task, args.fmi)
    print(f"wrote {path} ({os.path.getsize(path) / 1024:.0f} KiB, decoder {checkpoint}) "
          f"in {time.perf_counter() - started:.1f} s")
    return 0
