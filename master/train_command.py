"""`rhi train --decoder {conv,vae} [--config FILE] --out CKPT`, and the decoder-quality measure.

Settings come from :class:`components.vision.training.TrainSettings` defaults, overridden
by the ``[train]`` table of a TOML file. The training data are rendered once per
(samples, resolution, seed) and cached beside the checkpoint, so conv and vae trained
into the same folder share them.

Quality (:func:`hand_error`): the hand position read off a predicted image is found by
fitting the real camera to it, i.e. the angles whose rendering best matches the image
(least squares, Gauss-Newton from the true pose), then forward kinematics; the error is
the distance to the true hand. The same function also reports the visual-only inference
error: the angles whose *predicted* image best matches the true rendering (what the brain
would perceive from vision alone).

Example::

    metadata = train_decoder("conv", "results/conv.pt")
    model = load_decoder("results/conv.pt", resolution=64)
"""
from __future__ import annotations

import difflib
import time
from pathlib import Path

import numpy as np

from components.vision import checkpoint, training  # first: it configures torch's threads before torch loads
from components.vision.component import GenerativeModel
import torch  # noqa: E402

from components.body import camera, kinematics
from components.component import ComponentError
from master import training_data
from master.config import read_toml
from master.errors import ConfigError

SIGNATURE_TOLERANCE = 1e-3  # relative; the signature moves by far more when the camera changes
QUALITY_SEED = 12345        # held-out poses for the hand error, distinct from any training seed


def read_settings(path: str | None) -> training.TrainSettings:
    """Defaults overridden by the ``[train]`` table of the TOML file at ``path`` (if any)."""
    if path is None:
        return training.TrainSettings()
    table = read_toml(path).get("train", {})
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: [train] must be a table")
    names = training.TrainSettings.names()
    for key in table:
        if key not in names:
            close = difflib.get_close_matches(key, names, n=1)
            hint = f" (did you mean train.{close[0]}?)" if close else f" (known: {', '.join(names)})"
            raise ConfigError(f"{path}: unknown key train.{key}{hint}")
    try:
        return training.TrainSettings(**table)
    except ComponentError as error:
        raise ConfigError(f"{path}: {error}") from None


def data_path(folder: Path, settings: training.TrainSettings) -> Path:
    return folder / f"decoder-data-r{settings.resolution}-n{settings.samples}-s{settings.seed}.npz"


def fit_camera(images: np.ndarray, start_deg: np.ndarray, iterations: int = 6, delta: float = 0.5) -> np.ndarray:
    """Angles (N, 2) deg whose camera rendering best matches ``images`` (least squares, Gauss-Newton
    with central differences of ``delta`` deg, started at ``start_deg``)."""
    resolution = images.shape[-1]
    angles = np.array(start_deg, dtype=np.float64)
    for _ in range(iterations):
        residual = (camera.render(angles, resolution) - images).reshape(len(angles), -1)
        columns = []
        for joint in range(2):
            step = np.zeros(2)
            step[joint] = delta
            plus = camera.render(angles + step, resolution).reshape(len(angles), -1)
            minus = camera.render(angles - step, resolution).reshape(len(angles), -1)
            columns.append((plus - minus) / (2 * delta))
        angles = angles + _gauss_newton_step(np.stack(columns, axis=2), residual)
    return angles


def fit_decoder(model: GenerativeModel, images: np.ndarray, start_deg: np.ndarray, iterations: int = 20) -> np.ndarray:
    """Angles (N, 2) deg whose predicted image g(angles) best matches ``images`` (Gauss-Newton on J)."""
    angles = np.array(start_deg, dtype=np.float64)
    target = torch.from_numpy(np.ascontiguousarray(images, np.float32))
    for _ in range(iterations):
        with torch.no_grad():
            prediction, jacobian = model.predict_with_jacobian(torch.from_numpy(angles.astype(np.float32)))
        residual = (prediction - target).reshape(len(angles), -1).double().numpy()
        angles = angles + _gauss_newton_step(jacobian.reshape(len(angles), 2, -1).transpose(1, 2).double().numpy(),
                                             residual)
    return angles


def _gauss_newton_step(jacobian: np.ndarray, residual: np.ndarray, max_step: float = 5.0) -> np.ndarray:
    """Per row: -(J^T J + damping)^-1 J^T r, clipped to +-max_step deg; J (N, P, 2), r (N, P)."""
    gram = np.einsum("npk,npl->nkl", jacobian, jacobian)
    gram += 1e-6 * np.trace(gram, axis1=1, axis2=2)[:, None, None] * np.eye(2) + 1e-12 * np.eye(2)
    step = -np.linalg.solve(gram, np.einsum("npk,np->nk", jacobian, residual)[..., None])[..., 0]
    return np.clip(step, -max_step, max_step)


def hand_error(model: GenerativeModel, samples: int = 100, seed: int = QUALITY_SEED,
               fraction: float = 0.9) -> dict:
    """Hand-position errors (cm) of a decoder on held-out poses uniform over ``fraction`` of its ranges.

    read_off: hand of the camera pose fitted to the predicted image g(true pose);
    inference: hand of the decoder pose fitted to the true image. Each: mean, 95th percentile, max.
    The image MSE of the predictions on these poses is included.
    """
    poses = model.rest_pose + fraction * np.random.default_rng(seed).uniform(-1.0, 1.0, (samples, 2)) * model.half_ranges
    truth = camera.render(poses, model.resolution)
    with torch.no_grad():
        predicted = model(torch.from_numpy(poses.astype(np.float32))).numpy()
    true_hand = np.stack(kinematics.forward(poses[:, 0], poses[:, 1]), axis=1)
    result = {"poses": samples, "image_mse": float(np.mean((predicted - truth) ** 2))}
    for name, fitted in (("read_off", fit_camera(predicted, poses)), ("inference", fit_decoder(model, truth, poses))):
        error = 100 * np.linalg.norm(np.stack(kinematics.forward(fitted[:, 0], fitted[:, 1]), axis=1) - true_hand,
                                     axis=1)
        result[name] = {"mean_cm": float(error.mean()), "p95_cm": float(np.percentile(error, 95)),
                        "max_cm": float(error.max())}
    return result


def train_decoder(kind: str, out: str | Path, settings: training.TrainSettings | None = None,
                  progress: bool = True) -> dict:
    """Train a decoder of ``kind`` and save it to ``out``; returns the checkpoint metadata."""
    settings = settings or training.TrainSettings()
    out = Path(out)
    if not out.parent.is_dir():
        raise ConfigError(f"--out {out}: folder {out.parent} does not exist")
    started = time.perf_counter()
    data = training_data.cached(data_path(out.parent, settings), settings.samples, settings.resolution,
                                settings.seed, progress)
    data_seconds = time.perf_counter() - started
    model, report = training.train(kind, data.poses, data.images, data.rest_pose, data.half_ranges, settings,
                                   progress)
    metadata = training.checkpoint_metadata(kind, settings, data.rest_pose, data.half_ranges,
                                            data.content_hash, report)
    metadata["data_seconds"] = data_seconds
    metadata["camera_signature"] = training_data.camera_signature(settings.resolution)
    if settings.quality_poses:
        began = time.perf_counter()
        metadata["hand_error"] = hand_error(GenerativeModel(model.decoder, data.rest_pose, data.half_ranges),
                                            settings.quality_poses)
        metadata["quality_seconds"] = time.perf_counter() - began
    checkpoint.save(out, model, metadata)
    return metadata


def load_decoder(path: str | Path, resolution: int) -> GenerativeModel:
    """A trained decoder checked against today's camera at ``resolution`` and the body's rest pose and
    training ranges: CheckpointError (a ValueError naming the file) on any mismatch."""
    model = GenerativeModel.from_checkpoint(path, resolution, kinematics.REST_POSE, training_data.HALF_RANGES)
    stored = model.metadata.get("camera_signature")
    if stored is not None:
        now = training_data.camera_signature(resolution)
        if len(stored) != len(now) or not np.allclose(stored, now, rtol=SIGNATURE_TOLERANCE, atol=1e-6):
            raise checkpoint.CheckpointError(f"{path}: trained on images of another camera (its field of view "
                                             "or drawing changed since); retrain the decoder")
    return model


def run_train(args) -> int:
    """The body of `rhi train`: args has .decoder, .config, .out."""
    settings = read_settings(args.config)
    metadata = train_decoder(args.decoder, args.out, settings)
    errors = metadata.get("hand_error", {})
    print(f"{args.decoder} decoder ({settings.preset}, {settings.resolution} px) saved to {args.out}: "
          f"validation MSE {metadata['validation_mse']:.3g} after {metadata['epochs_run']} epochs "
          f"(best {metadata['best_epoch']}), {metadata['seconds']:.0f} s training + "
          f"{metadata['data_seconds']:.0f} s data")
    if errors:
        print(f"hand error on {errors['poses']} held-out poses: read off the prediction "
              f"{errors['read_off']['mean_cm']:.2f} cm mean ({errors['read_off']['max_cm']:.2f} max), "
              f"visual-only inference {errors['inference']['mean_cm']:.2f} cm mean "
              f"({errors['inference']['max_cm']:.2f} max)")
    return 0
