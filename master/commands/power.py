"""`rhi power --config FILE --contrast A-B --n 10,20,40 [--studies K] --out DIR`: the power of a within-participant
contrast, K simulated studies of n participants each (master/studies/power.py, docs/population.md)."""
from __future__ import annotations

import time

from rhi.master import config as configuration
from rhi.master.commands.experiment import add_model
from rhi.master.cosim import ConfigError
from rhi.master.outputs.files import check_output

HELP = "the power of a within-participant contrast (paired t test) over study sizes, by simulated studies"


def add_arguments(parser) -> None:
    """Add `rhi power`'s arguments to ``parser``."""
    parser.add_argument("--config", metavar="FILE", required=True,
                        help="an experiment configuration, its [population] the participants (docs/population.md)")
    add_model(parser)
    parser.add_argument("--contrast", default="sync-async", metavar="A-B",
                        help="two stimulations, each participant under both (default: sync-async)")
    parser.add_argument("--n", required=True, metavar="N,N,...", help="participants per study, e.g. 10,20,40")
    parser.add_argument("--studies", type=int, default=100, metavar="K", help="simulated studies per size "
                        "(default: 100; the power's Monte Carlo error is sqrt(p(1-p)/K))")
    parser.add_argument("--measure", default="drift_cm", help="the end-of-trial measure tested (default: drift_cm)")
    parser.add_argument("--condition", help="the condition (default: the configuration's first)")
    parser.add_argument("--decoder", help="the decoder slot (default: the configuration's first)")
    parser.add_argument("--alpha", type=float, default=0.05, help="the test's level (default: 0.05)")
    parser.add_argument("--out", metavar="DIR", required=True)
    parser.add_argument("--force", action="store_true", help="replace DIR if it holds other content")


def sizes(text: str) -> list[int]:
    """``"10,20,40"`` -> [10, 20, 40]; ConfigError unless each is a whole number of at least 2."""
    try:
        ns = [int(part) for part in text.split(",")]
    except ValueError:
        raise ConfigError(f"--n {text!r}: give whole numbers separated by commas, e.g. 10,20,40") from None
    if min(ns) < 2 or len(set(ns)) != len(ns):
        raise ConfigError(f"--n {text!r}: each size at least 2 participants, none twice")
    return sorted(ns)


def run(args) -> int:
    """Run `rhi power` into ``args.out``; returns the exit status."""
    started = time.perf_counter()
    config = configuration.load(args.config, model_name=args.model)
    ns = sizes(args.n)
    if args.studies < 1:
        raise ConfigError(f"--studies {args.studies}: at least 1")
    if not 0.0 < args.alpha < 1.0:
        raise ConfigError(f"--alpha {args.alpha}: a level in (0, 1)")
    from rhi.master.studies import power, report

    contrast = power.parse_contrast(args.contrast, config)
    report.check_measure(args.measure, config)
    check_output(args.out, args.force)
    simulate = power.protocol_simulator(config, contrast, args.measure, args.condition, args.decoder)
    curve = power.power(simulate, ns, args.studies, args.alpha)
    report.write(args.out, curve, config, vars(args), args.force, time.perf_counter() - started)
    print(f"wrote {args.out}: power.csv, power.png, run.json ({time.perf_counter() - started:.0f} s)")
    print(report.table(curve, args.measure), end="")
    return 0
