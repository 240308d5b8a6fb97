"""`rhi experiment`: the paper's protocol end to end, into DIR (docs/design.md, Command line contract)."""
from __future__ import annotations

import logging
import time
from pathlib import Path

from rhi.master import models
from rhi.master import config as configuration
from rhi.master.outputs.files import check_output


HELP = "run the paper's rubber-hand protocol"
log = logging.getLogger("rhi.experiment")


def add_arguments(parser) -> None:
    """Add `rhi experiment`'s arguments to ``parser``."""
    parser.add_argument("--config", metavar="FILE", help="TOML file overriding master/config/defaults.toml")
    parser.add_argument("--body", metavar="FMU|VARIANT", help="the body: an FMI 2.0 co-simulation FMU, or a body "
                        "variant run in this process (batched: the pymunk arm vectorised for cohorts; kinematic; "
                        "native, the default pymunk arm)")
    scale = parser.add_mutually_exclusive_group()
    scale.add_argument("--quick", action="store_true", help="a small version, for smoke tests")
    add_preset(scale)
    add_model(parser)
    parser.add_argument("--out", metavar="DIR", required=True)
    parser.add_argument("--force", action="store_true", help="replace DIR if it holds other content")
    parser.add_argument("--trials", type=int, help="trials per decoder x condition x stimulation")
    parser.add_argument("--steps", type=int, help="steps per trial")
    parser.add_argument("--seed", type=int, help="master seed")
    parser.add_argument("--resolution", type=int, help="camera and decoder resolution (pixels)")
    parser.add_argument("--conv-checkpoint", metavar="CKPT", help="a trained conv decoder")
    parser.add_argument("--vae-checkpoint", metavar="CKPT", help="a trained VAE decoder")
    add_device(parser)


def add_preset(parser) -> None:
    """Add ``--preset NAME`` (a shipped configuration, one of ``rhi.master.config.PRESETS``) to ``parser``."""
    parser.add_argument("--preset", choices=configuration.PRESETS,
                        help="a shipped configuration merged over the defaults, under --config: paper = 256x256 "
                             "and the paper's decoders (master/config/presets/paper_256.toml)")


def add_model(parser) -> None:
    """Add ``--model NAME`` (a registered model or ``FILE.py:Class``; default ``paper``) to ``parser``."""
    parser.add_argument("--model", default="paper", metavar="NAME",
                        help=f"the model (docs/model.md): {models.described()}; default: paper")


def add_device(parser) -> None:
    """Add ``--device`` (auto, cpu or cuda; default auto: where decoders train and run) to ``parser``."""
    parser.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto",
                        help="where decoders train and run: auto = cuda when torch sees a GPU, else cpu "
                             "(default: auto)")


def overrides(args) -> dict:
    """The configuration keys the options set, ``{"experiment.trials": 3, ...}``; an option not given is left out."""
    pairs = {"experiment.trials": args.trials, "experiment.steps": args.steps, "experiment.seed": args.seed,
             "experiment.resolution": args.resolution, "decoder.conv_checkpoint": args.conv_checkpoint,
             "decoder.vae_checkpoint": args.vae_checkpoint}
    return {key: value for key, value in pairs.items() if value is not None}


def run(args) -> int:
    """Run `rhi experiment` into ``args.out``; returns the exit status (0, or 1 when a trial failed, left out)."""
    started = time.perf_counter()
    config = configuration.load(args.config, overrides(args), quick=args.quick,  # before torch loads: fast refusals
                                preset_name=args.preset, model_name=args.model)
    check_output(args.out, args.force)
    from rhi.master.config.bodies import VARIANTS
    from rhi.master.runtime import contained

    if args.body and args.body not in VARIANTS and getattr(args, "argv", None) is not None \
            and not contained.inside():
        # an FMU's native code in a process of its own: a crash there is one line, exit 1 (a variant is rhi's)
        return contained.run_child(args.argv, "experiment", lambda: contained.clean_output(args.out))
    log.debug(f"model {models.of(config).name}: decoders {', '.join(config['experiment']['decoders'])}, "
              f"{len(config['experiment']['conditions'])} conditions x {len(config['experiment']['stimulations'])} "
              f"stimulations x {config['experiment']['trials']} trials x {config['experiment']['steps']} steps")
    from rhi.components.vision.component import resolve_device
    from rhi.master.runtime.context import RunContext
    from rhi.master.tasks import TASKS, run_into

    failures = run_into(TASKS["illusion"].with_body(args.body), args.out, config,
                        RunContext.of(args, progress=True, device=resolve_device(args.device))).failures
    for trial, error in failures.items():
        log.error(f"rhi experiment: trial failed and left out: {trial.decoder}/{trial.condition}/{trial.stimulation} "
                  f"trial {trial.index}: {error}")
    print(f"wrote {args.out}: summary.csv, trials.csv, run.json, figures/ "
          f"({time.perf_counter() - started:.0f} s)")
    print((Path(args.out) / "summary.csv").read_text(), end="")
    return 1 if failures else 0
