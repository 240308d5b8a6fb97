"""The causal model's pose encoders: trained (conv) or taken from the VAE (vae), calibrated, shipped.

For each decoder the causal model reads the seen arm's pose with an encoder
(:mod:`components.vision.pose_encoder`): the ``vae`` slot uses the VAE's own trained encoder, the
``conv`` slot an encoder of the same shape trained by Gaussian NLL on the same rendered data as the
decoders (:func:`master.decoders.training.prepare_data`, the ``[train]`` settings). Both are then
calibrated on CALIBRATION_POSES held-out poses (their own seed) and their coverage is measured on
COVERAGE_POSES others (another seed). The held-out images are those the brain sees: the arm with
the ball somewhere on its way to the hand (:func:`held_out`).

``python -m master.decoders.pose_encoders OUT_FOLDER`` trains and calibrates both at the default
settings and prints their coverage (the shipped files, master/decoders/checkpoints/pose-*.pt).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from components.body import camera, kinematics
from components.vision import checkpoint
from components.vision.networks import preset
from components.vision.pose_encoder import PoseModel, coverage, load_encoder, save_encoder, train_encoder, \
    variance_scale
from master.decoders import training_data
from master.decoders.training import prepare_data, train_settings

CALIBRATION_POSES, CALIBRATION_SEED = 500, 101
COVERAGE_POSES, COVERAGE_SEED = 500, 202
BALL_REACH = 0.25  # m: the ball is anywhere from the hand to this far forward of it (the stimulus' ball_distance)


def held_out(samples: int, seed: int, resolution: int, blur: float) -> tuple[np.ndarray, np.ndarray]:
    """Poses (N, 2) deg over the training ranges and their images with the ball at a random point of its path."""
    poses = training_data.sample_poses(samples, seed)
    hands = np.stack(kinematics.forward(poses[:, 0], poses[:, 1]), axis=1)
    rng = np.random.default_rng(seed + 1)
    balls = hands + np.stack([np.zeros(samples), rng.uniform(0.0, BALL_REACH, samples)], axis=1)
    images = np.concatenate([camera.render(poses[i:i + 256], resolution, balls[i:i + 256], blur=blur)
                             for i in range(0, samples, 256)])
    return poses, images


def calibrated(model: PoseModel, resolution: int, blur: float) -> PoseModel:
    """``model`` with its variance scale fitted on the calibration poses and its coverage (50/90 %) on others."""
    poses, images = held_out(CALIBRATION_POSES, CALIBRATION_SEED, resolution, blur)
    scale = variance_scale(*model.raw(images), poses)
    result = PoseModel(model.encoder, model.rest_pose, model.half_ranges, scale, model.metadata)
    poses, images = held_out(COVERAGE_POSES, COVERAGE_SEED, resolution, blur)
    angles, variance = result(images)
    covered = coverage(angles, variance, poses)
    result.metadata.update({
        "variance_scale": scale.tolist(),
        "coverage_50": covered[0.5].tolist(), "coverage_90": covered[0.9].tolist(),
        "rms_error_deg": np.sqrt(((angles - poses) ** 2).mean(axis=0)).tolist(),
        "median_sd_deg": np.sqrt(np.median(variance, axis=0)).tolist(),
        "held_out": f"{CALIBRATION_POSES} calibration poses (seed {CALIBRATION_SEED}), {COVERAGE_POSES} coverage "
                    f"poses (seed {COVERAGE_SEED}), ball on its path"})
    return result


def build(kind: str, config: dict, decoder_checkpoint: str, cache: Path, epochs: int = 30) -> PoseModel:
    """The calibrated pose encoder of decoder ``kind`` (conv: trained here; vae: the VAE's own encoder)."""
    settings = train_settings(config)
    blur = config["camera"]["blur"]
    sizes = preset(settings.preset)
    if kind == "vae":
        model, metadata = checkpoint.load(decoder_checkpoint, settings.resolution)
        encoder, history = model.encoder, {}
    else:
        cache.mkdir(parents=True, exist_ok=True)
        data = prepare_data(cache, settings, blur)
        encoder, history = train_encoder(data.poses, data.images, data.rest_pose, data.half_ranges, sizes,
                                         epochs=epochs, seed=settings.seed,
                                         progress=lambda e, n, loss: print(f"  epoch {e}/{n}: validation NLL "
                                                                           f"{loss:.4f}", file=sys.stderr))
    model = PoseModel(encoder, kinematics.REST_POSE, training_data.HALF_RANGES,
                      metadata={"kind": kind, "trained": "gaussian NLL on the decoders' data" if kind == "conv"
                                else "the VAE's encoder", "history": history})
    return calibrated(model, settings.resolution, blur)


def main(argv: list[str]) -> int:
    """``python -m master.decoders.pose_encoders OUT_FOLDER``: build both pose encoders at the default settings into
    ``argv[0]`` and print their calibration; returns the exit status, 0."""
    from master import config as configuration
    from master.decoders.cache import cache_folder, checkpoint_path, shipped_pose_encoder

    out = Path(argv[0])
    out.mkdir(parents=True, exist_ok=True)
    config = configuration.load()
    settings = train_settings(config)
    for kind in ("conv", "vae"):
        model = build(kind, config, checkpoint_path("vae", config, must_exist=True), cache_folder())
        path = out / shipped_pose_encoder(kind, settings.resolution).name
        save_encoder(path, model, preset(settings.preset), settings.resolution)
        shown = {key: model.metadata[key] for key in ("variance_scale", "coverage_50", "coverage_90",
                                                      "rms_error_deg", "median_sd_deg")}
        print(f"{path}: {json.dumps(shown)}")
        load_encoder(path)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
