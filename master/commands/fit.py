"""`rhi fit --data FILE.csv --config FIT.toml [--model paper|causal] [--scheduler ADDRESS] --out DIR`.

Fits the model's parameters to each participant of FILE.csv by neural posterior estimation, calibrated on
held-out simulated participants (docs/fit.md). Running the same command again after a stop runs only the
missing simulations and gives the same posterior (same seed).
"""
from __future__ import annotations

from pathlib import Path


HELP = "fit the model to participants' data by simulation-based inference, calibrated on held-out simulations"


def add_arguments(parser) -> None:
    """Add `rhi fit`'s arguments to ``parser``."""
    parser.add_argument("--data", metavar="FILE.csv", required=True,
                        help="one row per participant x observation: participant, the design, drift_cm (force_n)")
    parser.add_argument("--config", metavar="FIT.toml", required=True,
                        help="the fit file: parameters and priors, simulations, estimator (docs/fit.md)")
    parser.add_argument("--model", metavar="NAME",
                        help="the model, instead of the fit file's fit.model (default there: paper; a name or "
                             "FILE.py:Class, docs/model.md)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="a Dask scheduler, tcp://HOST:PORT (default: a process pool on this machine)")
    parser.add_argument("--out", metavar="DIR", required=True)


def run(args) -> int:
    """Run `rhi fit` (ConfigError without the sbi package) and print its summary; returns the exit status, 0."""
    import importlib.util

    from rhi.master.cosim import ConfigError
    from rhi.master.fit.run import fit
    from rhi.master.runtime.context import RunContext

    if importlib.util.find_spec("sbi") is None:  # an install without the fit extra
        raise ConfigError("rhi fit needs the sbi package: pip install -c constraints.txt -e '.[fit]' "
                          "(make setup installs it)")

    out = Path(args.out)
    result = fit(args.data, args.config, out, getattr(args, "model", None), RunContext.of(args))
    timing = result["posterior_seconds_per_participant"]
    line = (f"rhi fit: {len(result['participants'])} participants, {len(result['parameters'])} parameters, "
            f"{result['simulations']['participants']} simulated participants ({result['simulations']['trials']} "
            f"trials, {result['simulations']['trials_run_now']} run now); posterior {timing['mean']:.3f} s per "
            f"participant; {result['wall_s']:.0f} s; results in {out}")
    print(line)
    calibration = result.get("calibration")
    if calibration:
        for parameter in result["parameters"]:
            values = calibration[parameter["key"]]
            print(f"  {parameter['key']}: r = {values['correlation']:.3f}, coverage 50 % {values['coverage_50']:.2f}, "
                  f"90 % {values['coverage_90']:.2f}, SBC p = {values['sbc_chisquare_p']:.3f} (chi-square), "
                  f"{values['sbc_ks_p']:.3f} (KS)")
        from rhi.master.fit.calibration import verdict_words
        print(f"  SBC rank tests as one family (Bonferroni): {verdict_words(calibration['sbc_verdict'])}")
    return 0
