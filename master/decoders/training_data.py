"""Training data for the visual decoders: (joint angles, image) pairs from the real camera.

This is wiring (it needs the body's camera and kinematics and serves the vision
component), so it lives in master/. Poses are uniform over the rest pose +- 40 deg
(shoulder) and +- 50 deg (elbow); images are ``camera.render(poses, resolution, None, blur=blur)``:
the real arm alone, no ball, at the camera blur of the configuration (``[camera] blur``). A data set is written to ``.npz`` with its ranges,
resolution, seed and a content hash (sha256 of the arrays), and is checked against
that hash when read back.

Example::

    data = generate(samples=4000, resolution=64, seed=0)
    save("train.npz", data)
    data = cached("train.npz", samples=4000, resolution=64, seed=0)   # reuses the file if it matches
"""
from __future__ import annotations

import hashlib
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rhi.components.body import camera, kinematics
from rhi.master.config.protocol import HALF_RANGES
from rhi.master.cosim import ConfigError
from rhi.master.outputs.files import atomic_write

CHUNK = 256                 # poses rendered per call (bounds memory at 256 x 256)


@dataclass(frozen=True)
class TrainingData:
    """A rendered training set: poses and their camera images, and what made them.

    Attributes
    ----------
    poses : numpy.ndarray
        (N, 2) float64, deg: shoulder, elbow.
    images : numpy.ndarray
        (N, R, R) float32 in [0, 1]: the real arm alone, no ball.
    rest_pose : tuple of float
        (shoulder, elbow) deg, the centre of the poses' ranges.
    half_ranges : tuple of float
        (shoulder, elbow) deg: the poses are uniform over ``rest_pose +- half_ranges``.
    seed : int
        The seed the poses were drawn with.
    content_hash : str
        sha256 of the arrays (:func:`content_hash`).
    """

    poses: np.ndarray        # (N, 2) float64 deg: shoulder, elbow
    images: np.ndarray       # (N, R, R) float32 in [0, 1]
    rest_pose: tuple[float, float]
    half_ranges: tuple[float, float]
    seed: int
    content_hash: str        # sha256 of the arrays, see content_hash()

    @property
    def resolution(self) -> int:
        """R, the images' side in pixels."""
        return int(self.images.shape[-1])


def content_hash(poses: np.ndarray, images: np.ndarray) -> str:
    """sha256 over the dtype, shape and bytes of both arrays."""
    digest = hashlib.sha256()
    for array in (np.ascontiguousarray(poses, np.float64), np.ascontiguousarray(images, np.float32)):
        digest.update(f"{array.dtype.str}{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def sample_poses(samples: int, seed: int, rest_pose=kinematics.REST_POSE, half_ranges=HALF_RANGES) -> np.ndarray:
    """Joint angles (samples, 2) deg, uniform over rest +- half_ranges, from a seeded generator."""
    rng = np.random.default_rng(seed)
    return np.asarray(rest_pose) + rng.uniform(-1.0, 1.0, (samples, 2)) * np.asarray(half_ranges)


def generate(samples: int, resolution: int, seed: int, progress: bool = False,
             blur: float = camera.BLUR_SIGMA) -> TrainingData:
    """Render ``samples`` seeded (angles, image) pairs at ``resolution`` with the real camera (blur in m)."""
    poses = sample_poses(samples, seed)
    images = np.empty((samples, resolution, resolution), np.float32)
    chunks = range(0, samples, CHUNK)
    if progress:
        from rhi.master.runtime.progress import bar
        chunks = bar(chunks, desc="render", unit="chunk", leave=False)
    for start in chunks:
        images[start:start + CHUNK] = camera.render(poses[start:start + CHUNK], resolution, None, blur=blur)
    return TrainingData(poses, images, tuple(kinematics.REST_POSE), HALF_RANGES, seed,
                        content_hash(poses, images))


def save(path: str | os.PathLike, data: TrainingData) -> None:
    """Write ``data`` to ``path`` (.npz, uncompressed), atomically."""
    atomic_write(path, lambda file: np.savez(
        file, poses=data.poses, images=data.images, rest_pose=np.asarray(data.rest_pose),
        half_ranges=np.asarray(data.half_ranges), seed=np.int64(data.seed), content_hash=np.str_(data.content_hash)))


def load(path: str | os.PathLike) -> TrainingData:
    """Read a data set written by :func:`save`; ConfigError naming the file if it is unusable."""
    try:
        with np.load(path, allow_pickle=False) as file:
            fields = {name: file[name] for name in ("poses", "images", "rest_pose", "half_ranges", "seed",
                                                     "content_hash")}
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such training-data file") from None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as error:
        raise ConfigError(f"{path}: not a readable training-data file ({error})") from None
    poses, images = fields["poses"], fields["images"]
    if poses.ndim != 2 or poses.shape[1] != 2 or images.ndim != 3 or len(images) != len(poses):
        raise ConfigError(f"{path}: poses {poses.shape} and images {images.shape} do not form a data set")
    stored = str(fields["content_hash"])
    if content_hash(poses, images) != stored:
        raise ConfigError(f"{path}: content hash mismatch (the arrays were changed or damaged)")
    return TrainingData(poses, images, tuple(map(float, fields["rest_pose"])),
                        tuple(map(float, fields["half_ranges"])), int(fields["seed"]), stored)


def cached(path: str | os.PathLike, samples: int, resolution: int, seed: int, progress: bool = False,
           blur: float = camera.BLUR_SIGMA) -> TrainingData:
    """The data set at ``path`` if it was made with these settings and today's ranges, else a new one, saved.

    A cached file is also checked against a fresh rendering of its first pose (at ``blur``), so a
    camera that changed since the file was written is never trained on stale images.
    """
    if Path(path).exists():
        try:
            data = load(path)
        except ConfigError:
            data = None
        if (data is not None and len(data.poses) == samples and data.resolution == resolution
                and data.seed == seed and np.allclose(data.rest_pose, kinematics.REST_POSE, atol=1e-9)
                and np.allclose(data.half_ranges, HALF_RANGES) and np.array_equal(
                    data.poses, sample_poses(samples, seed))
                and np.array_equal(camera.render(data.poses[:1], resolution, None, blur=blur), data.images[:1])):
            return data
    data = generate(samples, resolution, seed, progress, blur)
    save(path, data)
    return data


def camera_signature(resolution: int, blur: float = camera.BLUR_SIGMA) -> list[float]:
    """A few numbers that change if the camera's geometry or drawing changes: the image sum and
    brightness-weighted centroid (px) of the rest pose and two poses at the range's corners, rendered
    at ``blur`` m. (A blur barely moves them: the checkpoint's stored camera_blur is checked too.)"""
    poses = np.asarray(kinematics.REST_POSE) + np.array([[0.0, 0.0], [1.0, 1.0], [-1.0, -1.0]]) * np.asarray(HALF_RANGES) * 0.75
    images = camera.render(poses, resolution, None, blur=blur)
    rows, columns = np.mgrid[:resolution, :resolution]
    signature = []
    for image in images.astype(np.float64):
        total = image.sum()
        signature += [total, (image * columns).sum() / total, (image * rows).sum() / total]
    return [round(float(v), 6) for v in signature]
