"""The causal and ownership models' pose encoders: trained (conv) or taken from the VAE (vae), calibrated, shipped.

For each decoder the causal model reads the seen arm's pose with an encoder
(:mod:`rhi.components.vision.pose_encoder`): the ``vae`` slot uses the VAE's own trained encoder, the
``conv`` slot an encoder of the same shape trained by Gaussian NLL on the same rendered data as the
decoders (:func:`rhi.master.decoders.training.prepare_data`, the ``[train]`` settings). Both are then
calibrated on CALIBRATION_POSES held-out poses (their own seed) and their coverage is measured on
COVERAGE_POSES others (another seed). The held-out images are those the brain sees: the arm with
the ball somewhere on its way to the hand (:func:`held_out`).

``python -m rhi.master.decoders.pose_encoders OUT_FOLDER`` trains and calibrates both at the default
settings and prints their coverage (the shipped files, master/decoders/checkpoints/pose-*.pt).

The ownership model reads rubber arms far beyond the decoders' ranges (its distance study puts the hand up
to 60 cm to the right, where the shoulder is at rest - 88 deg), so it has encoders of its own, trained and
calibrated over OWNERSHIP_BOX, which holds the rubber arm's poses over the arm's whole lateral reach and the
real arm's working range: conv trained from scratch, vae the VAE's encoder trained on from its own weights
(:func:`build_ownership`; the ``ownership`` model's ``pose_encoder_stem``), both on images drawn as the
decoders' are (the arm alone, :func:`box_data`) and calibrated as above over the box.
``python -m rhi.master.decoders.pose_encoders --ownership OUT_FOLDER`` makes both (pose-ownership-*.pt) and
prints their calibration and their reading of the rubber arm at each offset of OFFSETS, theirs and the
shipped encoders'.
"""
from __future__ import annotations

import copy
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from rhi.components.body import camera, kinematics
from rhi.components.vision import checkpoint
from rhi.components.vision.networks import preset
from rhi.components.vision.pose_encoder import PoseModel, coverage, load_encoder, save_encoder, train_encoder, \
    variance_scale
from rhi.master.config.protocol import HALF_RANGES, rubber_pose
from rhi.master.decoders import training_data
from rhi.master.decoders.training import prepare_data, train_settings

CALIBRATION_POSES, CALIBRATION_SEED = 500, 101
COVERAGE_POSES, COVERAGE_SEED = 500, 202
BALL_REACH = 0.25  # m: the ball is anywhere from the hand to this far forward of it (the stimulus' ball_distance)

# The ownership model's pose box, (low, high) deg per joint. The rubber arm posed by inverse kinematics at
# REST_HAND + (offset_x, 0) over the arm's whole lateral reach, offset_x from -0.430 to +0.630 m (a straight
# arm at both ends: elbow 0, shoulder 136.7 and 43.3 deg), runs over shoulder 43.3-158.5 and elbow -93.4-0;
# the real arm's working range rest +- HALF_RANGES (shoulder 107.7-187.7, elbow -141.2 to -41.2) holds the
# default protocol's Left/Center/Right. The box is their union, 5 deg beyond the reach's straight arms (an
# encoder is least accurate at its box's edges, where its training poses lie on one side only), in whole degrees.
# The camera's field ends at x = 0.17 m (camera.FIELD_X): the hand disc of 28 % of the box's poses, and the rubber
# hand beyond +0.42 m, is partly or wholly out of view (outside_field); the encoders read the rest of the arm.
OWNERSHIP_BOX = ((38.0, 188.0), (-142.0, 5.0))
OWNERSHIP_CENTRE = tuple((low + high) / 2.0 for low, high in OWNERSHIP_BOX)       # (113.0, -68.5)
OWNERSHIP_HALF_RANGES = tuple((high - low) / 2.0 for low, high in OWNERSHIP_BOX)  # (75.0, 73.5)
# Training poses: at least the shipped encoders' density, [train] samples = 3000 over 80 x 100 deg^2, so
# 3000 x (150 x 147) / 8000 = 8269 over the box; the seed and the epochs are the shipped conv build's.
OWNERSHIP_SAMPLES, OWNERSHIP_SEED, OWNERSHIP_EPOCHS = 8400, 0, 30
# Rubber-hand offsets (m, offset_y = 0) at which the encoders' readings are reported, and ball positions per offset
OFFSETS = tuple(round(0.05 * n, 2) for n in range(1, 13)) + tuple(round(-0.05 * n, 2) for n in range(1, 9))
BALL_POINTS = 11


def held_out(samples: int, seed: int, resolution: int, blur: float, rest_pose=kinematics.REST_POSE,
             half_ranges=HALF_RANGES) -> tuple[np.ndarray, np.ndarray]:
    """Poses (N, 2) deg uniform over rest_pose +- half_ranges (default: the training ranges) and their images
    with the ball at a random point of its path."""
    poses = training_data.sample_poses(samples, seed, rest_pose, half_ranges)
    hands = np.stack(kinematics.forward(poses[:, 0], poses[:, 1]), axis=1)
    rng = np.random.default_rng(seed + 1)
    balls = hands + np.stack([np.zeros(samples), rng.uniform(0.0, BALL_REACH, samples)], axis=1)
    images = np.concatenate([camera.render(poses[i:i + 256], resolution, balls[i:i + 256], blur=blur)
                             for i in range(0, samples, 256)])
    return poses, images


def calibrated(model: PoseModel, resolution: int, blur: float, rest_pose=kinematics.REST_POSE,
               half_ranges=HALF_RANGES) -> PoseModel:
    """``model`` with its variance scale fitted on the calibration poses and its coverage (50/90 %) on others,
    both drawn over rest_pose +- half_ranges (default: the decoders' training ranges)."""
    poses, images = held_out(CALIBRATION_POSES, CALIBRATION_SEED, resolution, blur, rest_pose, half_ranges)
    scale = variance_scale(*model.raw(images), poses)
    result = PoseModel(model.encoder, model.rest_pose, model.half_ranges, scale, model.metadata)
    poses, images = held_out(COVERAGE_POSES, COVERAGE_SEED, resolution, blur, rest_pose, half_ranges)
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


def renormalised(encoder, rest_pose, half_ranges, centre, new_half_ranges):
    """A copy of ``encoder`` whose outputs, read about ``centre`` +- ``new_half_ranges``, are the same angles
    and variances (deg) as the original's read about ``rest_pose`` +- ``half_ranges``.

    The last layer is linear (:class:`rhi.components.vision.networks.Encoder`), so the change of units is exact:
    mean' = (rest - centre) / h' + mean h / h', log-variance' = log-variance + 2 log(h / h') per joint.
    """
    result = copy.deepcopy(encoder)
    last = result.dense[-1]
    ratio = np.asarray(half_ranges, float) / np.asarray(new_half_ranges, float)
    shift = (np.asarray(rest_pose, float) - np.asarray(centre, float)) / np.asarray(new_half_ranges, float)
    with torch.no_grad():
        for joint in range(2):
            last.weight[joint] *= float(ratio[joint])
            last.bias[joint] = last.bias[joint] * float(ratio[joint]) + float(shift[joint])
            last.bias[2 + joint] += float(2.0 * np.log(ratio[joint]))
    return result


def box_data(samples: int, seed: int, resolution: int, blur: float) -> tuple[np.ndarray, np.ndarray]:
    """Training pairs over OWNERSHIP_BOX: poses (N, 2) deg, uniform, and their images as the decoders' training
    images are drawn (:func:`rhi.master.decoders.training_data.generate`: the arm alone, no ball, at ``blur``)."""
    poses = training_data.sample_poses(samples, seed, OWNERSHIP_CENTRE, OWNERSHIP_HALF_RANGES)
    images = np.concatenate([camera.render(poses[i:i + training_data.CHUNK], resolution, None, blur=blur)
                             for i in range(0, samples, training_data.CHUNK)])
    return poses, images


def build_ownership(kind: str, config: dict, decoder_checkpoint: str, epochs: int = OWNERSHIP_EPOCHS,
                    samples: int = OWNERSHIP_SAMPLES, data=None) -> PoseModel:
    """The ownership model's calibrated pose encoder of slot ``kind`` over OWNERSHIP_BOX: conv trained from
    scratch, vae trained on from the VAE's own encoder (``decoder_checkpoint``, :func:`renormalised` to the box,
    so it starts reading what the VAE reads); data: (poses, images) of :func:`box_data` to reuse."""
    settings = train_settings(config)
    blur = config["camera"]["blur"]
    sizes = preset(settings.preset)
    poses, images = data if data is not None else box_data(samples, OWNERSHIP_SEED, settings.resolution, blur)
    start = None
    if kind == "vae":
        vae, _ = checkpoint.load(decoder_checkpoint, settings.resolution)
        start = renormalised(vae.encoder, kinematics.REST_POSE, HALF_RANGES, OWNERSHIP_CENTRE, OWNERSHIP_HALF_RANGES)
    encoder, history = train_encoder(poses, images, OWNERSHIP_CENTRE, OWNERSHIP_HALF_RANGES, sizes, epochs=epochs,
                                     seed=OWNERSHIP_SEED, start=start,
                                     progress=lambda e, n, loss: print(f"  {kind} epoch {e}/{n}: validation NLL "
                                                                       f"{loss:.4f}", file=sys.stderr))
    trained = ("gaussian NLL on the ownership pose box" if kind == "conv"
               else "the VAE's encoder, trained on by gaussian NLL on the ownership pose box")
    model = PoseModel(encoder, OWNERSHIP_CENTRE, OWNERSHIP_HALF_RANGES, metadata={
        "kind": kind, "trained": trained, "history": history, "box_deg": [list(b) for b in OWNERSHIP_BOX],
        "samples": len(poses), "seed": OWNERSHIP_SEED, "epochs": epochs})  # no wall time: the same bytes each build
    result = calibrated(model, settings.resolution, blur, OWNERSHIP_CENTRE, OWNERSHIP_HALF_RANGES)
    result.metadata["held_out"] += " over the ownership pose box"
    return result


def outside_field(poses) -> dict[str, float]:
    """Fractions of ``poses`` (N, 2) deg whose hand disc, or elbow, is not wholly in the camera's field of view."""
    poses = np.asarray(poses, float)
    hand = np.stack(kinematics.forward(poses[:, 0], poses[:, 1]), axis=1)
    angle = np.radians(poses[:, 0])
    elbow = np.asarray(kinematics.SHOULDER) + kinematics.UPPER_ARM * np.stack([np.cos(angle), np.sin(angle)], axis=1)

    def out(points, margin):
        return ((points[:, 0] - margin < camera.FIELD_X[0]) | (points[:, 0] + margin > camera.FIELD_X[1])
                | (points[:, 1] - margin < camera.FIELD_Y[0]) | (points[:, 1] + margin > camera.FIELD_Y[1]))
    return {"hand_disc": float(out(hand, camera.HAND_RADIUS).mean()), "hand_centre": float(out(hand, 0.0).mean()),
            "elbow": float(out(elbow, camera.LIMB_WIDTH / 2).mean())}


def offset_table(model: PoseModel, resolution: int, blur: float, offsets=OFFSETS) -> list[dict]:
    """Per rubber-hand offset (m, offset_y = 0): the true pose, and the mean reading, its bias, rms error and
    calibrated sd (deg, per joint) over BALL_POINTS images with the ball evenly along its path."""
    rows = []
    for offset in offsets:
        truth = np.array(rubber_pose(offset))
        hand = np.array([kinematics.REST_HAND[0] + offset, kinematics.REST_HAND[1]])
        balls = hand + np.stack([np.zeros(BALL_POINTS), np.linspace(0.0, BALL_REACH, BALL_POINTS)], axis=1)
        poses = np.repeat(truth[None], BALL_POINTS, axis=0)
        angles, variance = model(camera.render(poses, resolution, balls, blur=blur))
        error = angles - truth
        rows.append({"offset_m": offset, "truth": truth.tolist(), "reading": angles.mean(axis=0).tolist(),
                     "bias": error.mean(axis=0).tolist(), "rms": np.sqrt((error ** 2).mean(axis=0)).tolist(),
                     "sd": np.sqrt(variance.mean(axis=0)).tolist()})
    return rows


def print_table(name: str, rows: list[dict]) -> None:
    """The rows of :func:`offset_table` as a text table on stdout."""
    print(f"{name}: offset m | truth shoulder, elbow | reading | bias | rms | sd (deg)")
    for row in rows:
        cells = [" ".join(f"{v:7.1f}" for v in row[key]) for key in ("truth", "reading", "bias", "rms", "sd")]
        print(f"  {row['offset_m']:+.2f} | " + " | ".join(cells))


def main_ownership(out: Path) -> int:
    """``--ownership OUT_FOLDER``: both ownership pose encoders into ``out``; their calibration and their and the
    shipped encoders' readings at OFFSETS on stdout."""
    from rhi.master import config as configuration, models
    from rhi.master.decoders.cache import checkpoint_path, shipped_pose_encoder

    torch.set_num_threads(1)  # each thread count rounds its own way: one, as [train] threads = 1
    config = configuration.load(model_name="ownership")
    settings, blur = train_settings(config), config["camera"]["blur"]
    stem = models.get("ownership").pose_encoder_stem
    box = training_data.sample_poses(100_000, 0, OWNERSHIP_CENTRE, OWNERSHIP_HALF_RANGES)
    print(f"box {OWNERSHIP_BOX} deg: fraction of poses out of the field of view {json.dumps(outside_field(box))}")
    began = time.perf_counter()
    data = box_data(OWNERSHIP_SAMPLES, OWNERSHIP_SEED, settings.resolution, blur)
    print(f"{OWNERSHIP_SAMPLES} training images rendered in {time.perf_counter() - began:.0f} s")
    for kind in ("conv", "vae"):
        began = time.perf_counter()
        model = build_ownership(kind, config, checkpoint_path("vae", config, must_exist=True), data=data)
        path = out / shipped_pose_encoder(kind, settings.resolution, stem).name
        save_encoder(path, model, preset(settings.preset), settings.resolution)
        shown = {key: model.metadata[key] for key in ("variance_scale", "coverage_50", "coverage_90",
                                                      "rms_error_deg", "median_sd_deg")}
        print(f"{path} ({time.perf_counter() - began:.0f} s): {json.dumps(shown)}")
        print_table(f"{kind} ownership", offset_table(load_encoder(path), settings.resolution, blur))
        print_table(f"{kind} shipped", offset_table(load_encoder(shipped_pose_encoder(kind, settings.resolution)),
                                                    settings.resolution, blur))
    return 0


def main(argv: list[str]) -> int:
    """``python -m rhi.master.decoders.pose_encoders [--ownership] OUT_FOLDER``: build both pose encoders at the default
    settings (the ownership model's with ``--ownership``) into the folder and print their calibration; returns
    the exit status, 0 (2 and a usage line for other arguments)."""
    from rhi.master import config as configuration
    from rhi.master.decoders.cache import cache_folder, checkpoint_path, shipped_pose_encoder

    if not argv or argv[-1].startswith("-") or argv[:-1] not in ([], ["--ownership"]):
        print("usage: python -m rhi.master.decoders.pose_encoders [--ownership] OUT_FOLDER", file=sys.stderr)
        return 2
    out = Path(argv[-1])
    out.mkdir(parents=True, exist_ok=True)
    if argv[0] == "--ownership":
        return main_ownership(out)
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
