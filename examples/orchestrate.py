"""The rubber-hand illusion wired by hand from the components and the engine, then with the body as an FMU.

One synchronous Left trial: the rubber hand 15 cm left of the real one, each touch felt 0-0.1 s after
it is seen. The drift is where the brain believes the hand is minus where it is (x, cm).

    python examples/orchestrate.py --checkpoint conv.pt     # a trained decoder at --resolution
    python examples/orchestrate.py --tiny --out tiny/       # a tiny one (16 px) trained first, into tiny/
"""
import argparse
import os
import tempfile
import time
from pathlib import Path

# Torch's OpenMP threads spin while they wait by default: on cores shared with other processes that cost this
# script several times its run time (as `rhi` sets it for itself, before torch loads).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402

from rhi.components.body import kinematics  # noqa: E402
from rhi.components.body.camera import Camera, render  # noqa: E402
from rhi.components.body.plant import ArmPlant  # noqa: E402
from rhi.components.body.rubber_arm import RubberArm  # noqa: E402
from rhi.components.brain.integrator import Brain  # noqa: E402
from rhi.components.body.contract import BODY_CONTRACT  # noqa: E402
from rhi.components.fmu import FMUComponent  # noqa: E402
from rhi.components.stimulus import Stimulus  # noqa: E402
from rhi.components.vision import checkpoint, training  # noqa: E402
from rhi.components.vision.component import Decoder  # noqa: E402
from rhi.master.cosim import System, simulate  # noqa: E402
from rhi.master.export.body import build_fmu  # noqa: E402

# Output -> input. simulate steps the components in the order the System lists them (Gauss-Seidel):
# the decoder reads this step's image and the belief mu of time t, the brain then integrates,
# and the body, last, moves under the new action.
CONNECTIONS = [
    ("rubber_arm.hand", "stimulus.target"),            # the ball touches the rubber hand
    ("rubber_arm.pose", "camera.arm_pose"),            # the camera sees the rubber arm ...
    ("stimulus.ball", "camera.ball"),                  # ... and the ball
    ("camera.image", "decoder.image"),
    ("brain.mu", "decoder.mu"),                        # the decoder predicts the image of the belief
    ("decoder.visual_drive", "brain.visual_drive"),
    ("decoder.visual_error", "brain.visual_error"),
    ("decoder.visual_stiffness", "brain.visual_stiffness"),
    ("stimulus.visual_time", "brain.visual_time"),     # when a touch was seen ...
    ("stimulus.tactile_time", "brain.tactile_time"),   # ... and felt
    ("body.q_shoulder", "brain.q_shoulder"),           # proprioception
    ("body.q_elbow", "brain.q_elbow"),
    ("brain.u_shoulder", "body.u_shoulder"),           # action
    ("brain.u_elbow", "body.u_elbow"),
]


FULL = {"steps": 1500, "resolution": 64}  # the experiment's trial: 30 s, 64x64 images
TINY = {"steps": 1500, "resolution": 16}  # the same 30 s trial, 16x16 images


def tiny_checkpoint(path, resolution):
    """A tiny conv decoder trained in seconds on camera images around the rest pose, saved at ``path``."""
    half_ranges = (40.0, 50.0)  # deg about the rest pose, as the experiment's decoders are trained
    poses = np.asarray(kinematics.REST_POSE) + np.random.default_rng(0).uniform(-1, 1, (400, 2)) * half_ranges
    settings = training.TrainSettings(samples=400, epochs=8, patience=8, preset="tiny", resolution=resolution,
                                      quality_poses=0)
    model, report = training.train("conv", poses, render(poses, resolution), kinematics.REST_POSE, half_ranges,
                                   settings, progress=False)
    with open(path, "wb") as file:
        checkpoint.write(file, model, training.checkpoint_metadata("conv", settings, kinematics.REST_POSE,
                                                                   half_ranges, "tiny example data", report))
    return path


def drift_cm(args, body):
    """Run the trial with this body and return its final drift, cm."""
    decoder = Decoder(args.checkpoint, resolution=args.resolution, rest_pose=kinematics.REST_POSE)
    system = System([RubberArm(), Stimulus(), Camera(resolution=args.resolution), decoder, Brain(), body],
                    CONNECTIONS)
    result = simulate(system, stop_time=args.steps * 0.02, step_size=0.02, batch_size=1, parameters={
        "rubber_arm.offset_x": -0.15,                          # Left: 15 cm left of the real hand
        "stimulus.delay_min": 0.0, "stimulus.delay_max": 0.1,  # synchronous: felt 0-0.1 s after seen
        "stimulus.seed": args.seed,
        "decoder.visual_variance": args.visual_variance,
        "brain.mu0": kinematics.REST_POSE,                     # the belief starts at the true rest pose
    }, record=["brain.mu", "body.q_shoulder", "body.q_elbow"])
    # result.values[path] has shape (steps + 1, batch, *shape); the drift is taken after the last step.
    final = {path: values[-1, 0] for path, values in result.values.items()}
    believed_x, _ = kinematics.forward(*final["brain.mu"])     # where the brain believes the hand is
    sensed_x, _ = kinematics.forward(final["body.q_shoulder"], final["body.q_elbow"])  # where it is
    return 100.0 * float(believed_x - sensed_x)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", help="a trained decoder (.pt) at --resolution")
    parser.add_argument("--tiny", action="store_true",
                        help=f"train a tiny decoder first (default --resolution {TINY['resolution']}, --steps "
                             f"{TINY['steps']}: about 40 s of CPU time)")
    parser.add_argument("--out", metavar="DIR", help="with --tiny: keep its decoder as DIR/tiny_decoder.pt "
                                                     "(default: a temporary folder, removed at the end)")
    parser.add_argument("--steps", type=int, help="steps of 0.02 s (default 1500: 30 s)")
    parser.add_argument("--resolution", type=int, help="camera and decoder image side, px (default 64)")
    # 20.0 is the calibrated value; master/config/defaults.toml ([decoder] visual_variance) holds the default.
    parser.add_argument("--visual-variance", type=float, default=20.0)
    parser.add_argument("--seed", type=int, default=1, help="seeds the stimulus's visuo-tactile delays")
    args = parser.parse_args()
    if args.tiny == bool(args.checkpoint):
        parser.error("give --checkpoint PATH (a trained decoder) or --tiny")
    if args.out and not args.tiny:
        parser.error("--out names the folder of --tiny's decoder")
    for key, value in (TINY if args.tiny else FULL).items():
        if getattr(args, key) is None:
            setattr(args, key, value)

    began = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        if args.tiny:
            kept = Path(args.out or folder)
            kept.mkdir(parents=True, exist_ok=True)
            print(f"training a tiny decoder ({args.resolution} px) into {kept / 'tiny_decoder.pt'}", flush=True)
            args.checkpoint = tiny_checkpoint(kept / "tiny_decoder.pt", args.resolution)
        print(f"one synchronous Left trial of {args.steps} steps, with the native body, then the FMU", flush=True)
        print(f"native body: drift {drift_cm(args, ArmPlant()):.12f} cm", flush=True)
        fmu = build_fmu(Path(folder) / "Body.fmu", "native")  # the same body, exported as an FMI 2.0 FMU
        print(f"FMU body:    drift {drift_cm(args, FMUComponent(fmu, 'body', BODY_CONTRACT)):.12f} cm")
    print(f"done in {time.perf_counter() - began:.0f} s")


if __name__ == "__main__":
    main()
