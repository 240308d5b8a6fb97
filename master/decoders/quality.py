"""How good a trained decoder is: the hand position read off its images, in cm.

Read off (:func:`hand_error`): the hand position read off a predicted image is found by fitting
the real camera to it, i.e. the angles whose rendering best matches the image (least squares,
Gauss-Newton from the true pose), then forward kinematics; the error is the distance to the true
hand. The same function also reports the visual-only inference error: the angles whose
*predicted* image best matches the true rendering (what the brain would perceive from vision alone).
"""
from __future__ import annotations

import numpy as np
import torch

from rhi.components.body import camera, kinematics
from rhi.components.vision.component import GenerativeModel

QUALITY_SEED = 12345        # held-out poses for the hand error, distinct from any training seed
STOP_SEED = 54321           # held-out poses of the hand-error check that may stop training, distinct from both


def fit_camera(images: np.ndarray, start_deg: np.ndarray, iterations: int = 6, delta: float = 0.5,
               blur: float = camera.BLUR_SIGMA) -> np.ndarray:
    """Angles (N, 2) deg whose camera rendering (blurred by ``blur`` m) best matches ``images`` (least
    squares, Gauss-Newton with central differences of ``delta`` deg, started at ``start_deg``)."""
    resolution = images.shape[-1]
    angles = np.array(start_deg, dtype=np.float64)
    for _ in range(iterations):
        residual = (camera.render(angles, resolution, blur=blur) - images).reshape(len(angles), -1)
        columns = []
        for joint in range(2):
            step = np.zeros(2)
            step[joint] = delta
            plus = camera.render(angles + step, resolution, blur=blur).reshape(len(angles), -1)
            minus = camera.render(angles - step, resolution, blur=blur).reshape(len(angles), -1)
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
            prediction, jacobian = prediction.cpu(), jacobian.cpu()  # no copy on the CPU
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
               fraction: float = 0.9, blur: float = camera.BLUR_SIGMA) -> dict:
    """Hand-position errors (cm) of a decoder on held-out poses uniform over ``fraction`` of its ranges,
    against the camera at ``blur`` m (the one the decoder was trained on).

    read_off: hand of the camera pose fitted to the predicted image g(true pose);
    inference: hand of the decoder pose fitted to the true image. Each: mean, 95th percentile, max.
    The image MSE of the predictions on these poses is included.
    """
    poses = held_out_poses(model, samples, seed, fraction)
    truth = camera.render(poses, model.resolution, blur=blur)
    with torch.no_grad():
        predicted = model(torch.from_numpy(poses.astype(np.float32))).cpu().numpy()
    true_hand = np.stack(kinematics.forward(poses[:, 0], poses[:, 1]), axis=1)
    result = {"poses": samples, "image_mse": float(np.mean((predicted - truth) ** 2))}
    for name, fitted in (("read_off", fit_camera(predicted, poses, blur=blur)),
                         ("inference", fit_decoder(model, truth, poses))):
        error = 100 * np.linalg.norm(np.stack(kinematics.forward(fitted[:, 0], fitted[:, 1]), axis=1) - true_hand,
                                     axis=1)
        result[name] = {"mean_cm": float(error.mean()), "p95_cm": float(np.percentile(error, 95)),
                        "max_cm": float(error.max())}
    return result


def held_out_poses(model: GenerativeModel, samples: int, seed: int, fraction: float = 0.9) -> np.ndarray:
    """Poses (samples, 2) deg uniform over ``fraction`` of the model's training ranges, from ``seed``."""
    return model.rest_pose + fraction * np.random.default_rng(seed).uniform(-1.0, 1.0, (samples, 2)) * model.half_ranges


def read_off_error(model: GenerativeModel, samples: int, seed: int = STOP_SEED, fraction: float = 0.9,
                   blur: float = camera.BLUR_SIGMA) -> float:
    """Mean hand error (cm) read off the predictions at ``samples`` held-out poses (as :func:`hand_error`'s
    read_off, without the inference fit): the cheap check that may stop training."""
    poses = held_out_poses(model, samples, seed, fraction)
    with torch.no_grad():
        predicted = model(torch.from_numpy(poses.astype(np.float32))).cpu().numpy()
    fitted = fit_camera(predicted, poses, blur=blur)
    true_hand = np.stack(kinematics.forward(poses[:, 0], poses[:, 1]), axis=1)
    hand = np.stack(kinematics.forward(fitted[:, 0], fitted[:, 1]), axis=1)
    return float(100 * np.linalg.norm(hand - true_hand, axis=1).mean())
