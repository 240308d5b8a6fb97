"""`rhi phenomenon NAME [--config FILE] [--scheduler ADDRESS] [--force] --out DIR`: one human phenomenon.

Runs the phenomenon's sweep (the shipped file master/phenomena/NAME.toml, or an edited copy given
with --config) exactly as `rhi sweep` does, resumably, once per model (``--model``, default both:
the paper's into DIR/paper, the causal one into DIR/causal with ``causal.participants`` trials per
point), then writes DIR/NAME.csv and DIR/NAME.png, the models beside the human reference
(master/phenomena/human.toml).
"""
from __future__ import annotations

import time
from pathlib import Path

from rhi.master import models as registry
from rhi.master.phenomena import NAMES, sweep_file

BOTH = ("paper", "causal")  # --model both: these side by side (a model's own name runs it alone)
OWN_PROTOCOLS = ("moving-hand", "reach-after")  # not sweeps: registered tasks (rhi.master.tasks.TASKS)


HELP = "a human phenomenon (temporal window, distance, time course, ...): the models beside the human data"


def add_arguments(parser) -> None:
    """Add `rhi phenomenon`'s arguments to ``parser``."""
    parser.add_argument("name", choices=NAMES + OWN_PROTOCOLS, help="the phenomenon")
    parser.add_argument("--config", metavar="FILE",
                        help="a sweep file to use instead of the shipped one (copy master/phenomena/NAME.toml)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="a Dask scheduler, tcp://HOST:PORT (default: a process pool on this machine)")
    parser.add_argument("--out", metavar="DIR", required=True)
    parser.add_argument("--force", action="store_true", help="replace a different sweep in DIR")
    parser.add_argument("--model", default="both", metavar="NAME",
                        help="the model to run, or both: paper and causal side by side on one figure (default: both; "
                             "a name or FILE.py:Class, docs/model.md)")


def run(args) -> int:
    """Run `rhi phenomenon NAME`: its own protocol, or its sweep once per model and the report; returns the exit
    status (the sweeps' highest: 1 when a trial failed)."""
    from rhi.master.commands.sweep import sweep_and_report
    from rhi.master.runtime.context import RunContext
    from rhi.master.phenomena.report import report

    from rhi.master.outputs.files import cannot_write
    from rhi.master.outputs.own_paths import make_folder
    from rhi.master.sweeps import plan
    from rhi.master.sweeps.folder import check_folder
    from rhi.master.sweeps.runner import check_decoders

    started, out, context = time.perf_counter(), Path(args.out), RunContext.of(args)  # its address checked first
    if args.name in OWN_PROTOCOLS:
        from rhi.master.tasks import TASKS, run_into

        task = TASKS[args.name]
        config = task.load(args.config, model_name="paper" if args.model == "both" else args.model)
        run_into(task, out, config, context)
        written = sorted(path.name for path in out.iterdir())
        written = [*(name for name in written if name.endswith(".csv")), *(name for name in written
                                                                          if not name.endswith(".csv"))]
        print(f"rhi phenomenon {args.name}: wrote {', '.join(str(out / name) for name in written)} "
              f"({time.perf_counter() - started:.0f} s)")
        print((out / written[0]).read_text(), end="")
        return 0
    path = Path(args.config) if args.config else sweep_file(args.name)
    chosen = BOTH if getattr(args, "model", "both") == "both" else (args.model,)
    # a model of a population: its trials per point as the sweep file sets them ([causal] participants), else its own
    per_point = {model: registry.get(model).trials_per_point(plan.base_config(path, model)[0]) for model in chosen}
    trials = {model: count for model, count in per_point.items() if count}  # a population: one participant a trial
    for model in chosen:  # every model's points, decoders and pose encoders checked before anything is written
        check_decoders(plan.load(path, model, trials.get(model)))
    check_folder(out)
    own = report_manifest(out, args.name)
    check_ours(out, [registry.get(model).name for model in chosen])
    try:
        created = make_folder(out)  # this run's to remove again (if still empty) only if this process made it
    except OSError as error:  # read-only, no permission: a refusal (2); a full disk: the machine's (1)
        raise cannot_write(out.absolute().parent, error) from None
    try:
        folders, status = {}, 0
        for model in chosen:
            folders[model] = out / registry.get(model).name
            status = max(status, sweep_and_report(path, folders[model], context, model, trials.get(model)))
        written = report(args.name, path, out, folders, trials)
        for name in written:
            own.add(name)
        own.save()
    except BaseException:  # refused or stopped before any file: the folder this run made goes, as it came
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        raise
    print(f"rhi phenomenon {args.name}: wrote {', '.join(str(out / name) for name in written)} "
          f"({time.perf_counter() - started:.0f} s)")
    print((out / written[0]).read_text(), end="")
    return status


COMMAND = "rhi phenomenon"  # the manifest's "command" in DIR: the report's files are rhi phenomenon's


def report_manifest(out: Path, name: str):
    """DIR's manifest (rhi.master.outputs.manifest), checked before anything runs: the report's files NAME.csv and
    NAME.png, when there, must be the ones rhi phenomenon wrote, unchanged; else a ConfigError naming them."""
    from rhi.master.cosim import ConfigError
    from rhi.master.outputs.manifest import NAME, Manifest
    from rhi.master.phenomena import FILES

    own = Manifest.read(out, COMMAND) or Manifest(out, COMMAND)
    stem = FILES[name].removesuffix(".toml")
    blocking = [file for file in (f"{stem}.csv", f"{stem}.png")
                if ((out / file).exists() or (out / file).is_symlink()) and not own.proven(file)]
    if blocking:
        raise ConfigError(f"output folder {out}: {', '.join(blocking)} would be written over but "
                          f"{'is' if len(blocking) == 1 else 'are'} not what rhi phenomenon wrote there (not in its "
                          f"{NAME}, or changed since): move {'it' if len(blocking) == 1 else 'them'} or choose "
                          "another --out")
    return own


def check_ours(out: Path, folders: list[str]) -> None:
    """ConfigError unless DIR is new, empty, or an earlier `rhi phenomenon` output: its manifest (written when a
    run ends), or, of a run stopped before that, nothing but the models' sweep ``folders`` (each rhi's sweep, or
    what a sweep cut short leaves). With or without --force: a phenomenon never writes into another's folder
    (an experiment's output, a user's)."""
    from rhi.master.cosim import ConfigError
    from rhi.master.outputs.manifest import Manifest
    from rhi.master.sweeps.folder import only_leftovers, read_manifest

    if not out.is_dir() or Manifest.read(out, COMMAND) is not None:
        return
    strays = sorted(entry.name for entry in out.iterdir()
                    if not (entry.name in folders and entry.is_dir() and not entry.is_symlink()
                            and (read_manifest(entry / "sweep.json") is not None or only_leftovers(entry))))
    if strays:
        shown = ", ".join(strays[:5]) + (f" and {len(strays) - 5} more" if len(strays) > 5 else "")
        raise ConfigError(f"output folder {out} is not empty and holds no rhi phenomenon output (it holds {shown}); "
                          "a phenomenon writes only into a new folder or its own, with or without --force: choose "
                          "another --out")
