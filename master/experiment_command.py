"""`rhi experiment`: the paper's protocol end to end, into DIR (DESIGN.md, Command line contract)."""
from __future__ import annotations

import json
import shutil
import sys
import time

import numpy as np

from master import config as configuration
from master.results import atomic_write, package_versions


def add_arguments(parser) -> None:
    parser.add_argument("--config", metavar="FILE", help="TOML file overriding master/defaults.toml")
    parser.add_argument("--body", metavar="FMU", help="an FMI 2.0 co-simulation FMU to use as the body")
    parser.add_argument("--quick", action="store_true", help="a small version, for smoke tests")
    parser.add_argument("--out", metavar="DIR", required=True)
    parser.add_argument("--force", action="store_true", help="replace DIR if it holds other content")
    parser.add_argument("--trials", type=int, help="trials per decoder x condition x stimulation")
    parser.add_argument("--steps", type=int, help="steps per trial")
    parser.add_argument("--seed", type=int, help="master seed")
    parser.add_argument("--resolution", type=int, help="camera and decoder resolution (pixels)")
    parser.add_argument("--conv-checkpoint", metavar="CKPT", help="a trained conv decoder")
    parser.add_argument("--vae-checkpoint", metavar="CKPT", help="a trained VAE decoder")


def overrides(args) -> dict:
    pairs = {"experiment.trials": args.trials, "experiment.steps": args.steps, "experiment.seed": args.seed,
             "experiment.resolution": args.resolution, "decoder.conv_checkpoint": args.conv_checkpoint,
             "decoder.vae_checkpoint": args.vae_checkpoint}
    return {key: value for key, value in pairs.items() if value is not None}


def body_factory(path):
    """A callable making the body component: the native plant, or the FMU at ``path``."""
    if path is None:
        return None
    from components.fmu_adapter import FMUComponent

    FMUComponent(path, name="body")  # checks the body contract now, listing every problem, before any work
    return lambda: FMUComponent(path, name="body")


def run_experiment(args) -> int:
    from master import experiment, figures, outputs
    from master.animation import frames, gif_bytes
    from master.decoders import ensure_checkpoints, jacobian_pair

    started = time.perf_counter()
    config = configuration.load(args.config, overrides(args), quick=args.quick)
    make_body = body_factory(args.body)
    staging = outputs.staging_folder(args.out, args.force)
    try:
        checkpoints, training_seconds = ensure_checkpoints(config, progress=True)
        trials, times, per_step, run_seconds, failures = experiment.run(config, checkpoints, make_body,
                                                                        progress=True)
        final = {key: values[-1] for key, values in per_step.items()}
        atomic_write(staging / "summary.csv", outputs.csv_text(outputs.SUMMARY_COLUMNS, outputs.summary(trials, final)))
        atomic_write(staging / "trials.csv", outputs.trials_csv(trials, times, per_step))
        jacobians = {kind: jacobian_pair(kind, checkpoints[kind], config) for kind in checkpoints}
        written = figures.write_all(staging / "figures", trials, times, per_step, jacobians)
        shown = next((i for i, t in enumerate(trials) if (t.condition, t.stimulation) == ("left", "sync")), 0)
        rubber_pose = experiment.rubber_pose(trials[shown].offset_x)
        balls = np.stack([per_step["ball_x_m"][:, shown], per_step["ball_y_m"][:, shown]], axis=1)
        mu = np.stack([per_step["mu_shoulder_deg"][:, shown], per_step["mu_elbow_deg"][:, shown]], axis=1)
        name = f"trial_{trials[shown].decoder}_{trials[shown].condition}_{trials[shown].stimulation}.gif"
        atomic_write(staging / "figures" / name,
                     gif_bytes(frames(mu, rubber_pose, balls, config["experiment"]["resolution"])))
        provenance = {
            "command": "rhi experiment", "configuration": config, "body": args.body or "native pymunk plant",
            "checkpoints": checkpoints, "seeds": {"master": config["experiment"]["seed"],
                                                  "trials": [t.__dict__ for t in trials]},
            "versions": package_versions(),
            "timings_s": {"training": training_seconds, "trials": run_seconds,
                          "total": time.perf_counter() - started},
            "figures": written + [name],
            "failed_trials": [{**trial.__dict__, "error": error} for trial, error in failures.items()],
        }
        atomic_write(staging / "run.json", json.dumps(provenance, indent=2, default=str) + "\n")
        outputs.publish(staging, args.out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    print(f"wrote {args.out}: summary.csv, trials.csv, run.json, figures/ "
          f"({time.perf_counter() - started:.0f} s)")
    print((outputs.Path(args.out) / "summary.csv").read_text(), end="")
    for trial, error in failures.items():
        print(f"rhi experiment: trial failed and left out: {trial.decoder}/{trial.condition}/{trial.stimulation} "
              f"trial {trial.index}: {error}", file=sys.stderr)
    return 1 if failures else 0


