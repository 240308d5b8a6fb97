"""The pose encoder: the seen arm's joint angles and their variance, read from the image.

The causal model's visual evidence lives in body space (docs/model.md): an encoder q reads the
camera image and returns, per trial, the seen arm's joint angles x_v (deg) and a variance per
joint (deg^2), the visual observation the brain weighs by its precision.

- Network: the VAE's convolutional encoder (:class:`rhi.components.vision.networks.Encoder`), a mean
  and a log-variance in the decoders' normalised joint units. For the ``vae`` decoder it *is* the
  VAE's trained encoder; for the ``conv`` decoder one of the same shape is trained here, on the
  same rendered (angles, image) pairs, by :func:`train_encoder`.
- Training loss: the Gaussian negative log-likelihood (:func:`gaussian_nll`), so that the
  log-variance learns how far the mean is from the truth (Nix & Weigend 1994).
- Calibration: one factor per joint multiplies the variance so that the standardised squared
  residuals average 1 on held-out poses (:func:`variance_scale`, variance scaling as in Levi et al.
  2022, Sensors 22:5540); :func:`coverage` then reports how often the central 50 % and 90 %
  intervals hold the true angle, on other held-out poses.

Example::

    encoder = PoseEncoder(load_encoder("pose-conv.pt"))
"""
from __future__ import annotations

import copy
import os

import numpy as np
import torch

from ..component import Component, ComponentError, StepFailure
from ..variables import Variable
from .component import available_cores
from .image_sharing import FeatureStore, digest, distinct, weights_key
from .networks import Encoder, normalise, sizes_dict, sizes_from_dict

FORMAT = "rhi-pose-encoder/1"
MIN_ROWS = 2      # images per convolution call at least: torch on the CPU convolves a batch of one another way (other bits)
DENSE_ROWS = 4    # rows per dense-layer call at least: below 4 rows torch's CPU matrix product gives a row other bits
                  # than in a batch of any larger size (measured on AVX2 with torch 2.13; the check at initialization
                  # falls back to the unshared path wherever that does not hold)
STORE_MB = 64.0   # the process's store of convolution features: 2 KiB an image at 64 px, so ~30 000 images
STORE = FeatureStore(STORE_MB)  # one per process: a fit's batches, one after another, show the same pictures


def gaussian_nll(mean, log_variance, target):
    """Mean Gaussian negative log-likelihood of ``target`` under N(mean, exp(log_variance)), up to log 2 pi / 2.

    Nix & Weigend 1994 (Proc. IEEE ICNN): 1/2 [log s^2 + (y - m)^2 / s^2], averaged over (B, 2).
    torch's GaussianNLLLoss on the variance, so the formula is the library's, not a hand-written one.
    """
    return torch.nn.functional.gaussian_nll_loss(mean, target, log_variance.exp(), full=False, eps=1e-8)


def variance_scale(mean, variance, truth) -> np.ndarray:
    """Per joint (2,): the factor c with mean((truth - mean)^2 / (c variance)) = 1 on held-out poses.

    Variance scaling (Levi, Gispan, Giladi & Fetaya 2022, Sensors 22:5540): the maximum-likelihood
    scale of a Gaussian's variance given the residuals, c = mean(r^2 / s^2). (N, 2) arrays in.
    """
    residual = np.asarray(truth, float) - np.asarray(mean, float)
    return (residual ** 2 / np.asarray(variance, float)).mean(axis=0)


def coverage(mean, variance, truth, levels=(0.5, 0.9)) -> dict[float, np.ndarray]:
    """Per level, per joint (2,): the fraction of poses whose true angle lies in the central interval.

    The interval at level p is mean +- z sd with z = Phi^-1((1 + p) / 2) (scipy's normal quantile).
    """
    z_scores = np.abs(np.asarray(truth, float) - np.asarray(mean, float)) / np.sqrt(np.asarray(variance, float))
    from scipy.stats import norm  # here, not at the top: a refused command never pays for scipy.stats

    return {level: (z_scores <= norm.ppf(0.5 + level / 2.0)).mean(axis=0) for level in levels}


class PoseModel:
    """q(image) -> (angles, variance): a trained encoder behind the normalisation and the calibration.

    encoder: :class:`Encoder` (images (B, R, R) -> normalised mean and log-variance, (B, 2) each);
    rest_pose, half_ranges: deg, the normalisation's; scale: (2,) the calibration factor of the variance.
    """

    def __init__(self, encoder: Encoder, rest_pose, half_ranges, scale=(1.0, 1.0), metadata: dict | None = None):
        self.encoder = encoder.float().eval().requires_grad_(False)
        self.rest_pose = np.array(rest_pose, dtype=np.float64)
        self.half_ranges = np.array(half_ranges, dtype=np.float64)
        self.scale = np.array(scale, dtype=np.float64)
        self.metadata = dict(metadata or {})

    def raw(self, images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Uncalibrated angles and variances, (B, 2) deg and deg^2, of images (B, R, R)."""
        with torch.no_grad():
            mean, log_variance = self.encoder(torch.from_numpy(np.ascontiguousarray(images, np.float32)))
        return self._angles(mean, log_variance)

    def features(self, images: np.ndarray) -> np.ndarray:
        """The convolutional stages' output (B, C, s, s) float32 of images (B, R, R): the encoder's first half."""
        with torch.no_grad():
            return self.encoder.convolutions(torch.from_numpy(np.ascontiguousarray(images, np.float32))[:, None]).numpy()

    def from_features(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Calibrated angles and variances (B, 2) of :meth:`features`' output (B, C, s, s): the encoder's second
        half, the same operations as :meth:`__call__` after the convolutions."""
        with torch.no_grad():
            out = self.encoder.dense(torch.from_numpy(features))
        angles, variance = self._angles(out[:, :2], out[:, 2:])
        return angles, variance * self.scale

    def _angles(self, mean, log_variance) -> tuple[np.ndarray, np.ndarray]:
        angles = self.rest_pose + mean.double().numpy() * self.half_ranges
        return angles, np.exp(log_variance.double().numpy()) * self.half_ranges ** 2

    def __call__(self, images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Calibrated angles (B, 2) deg and variances (B, 2) deg^2 of images (B, R, R)."""
        angles, variance = self.raw(images)
        return angles, variance * self.scale


def train_encoder(poses_deg, images, rest_pose, half_ranges, sizes, epochs: int = 20, batch_size: int = 32,
                  lr: float = 1e-3, seed: int = 0, validation_fraction: float = 0.1, start: Encoder | None = None,
                  progress=None) -> tuple[Encoder, dict]:
    """An encoder trained by :func:`gaussian_nll` on (pose, image) pairs; seeded and deterministic.

    poses_deg (N, 2), images (N, R, R) float32; sizes: a networks.Preset; start: an encoder to begin
    from (a copy; e.g. the VAE's). The best epoch on the validation split is kept. Returns the encoder
    and {"train_nll", "validation_nll"} per epoch.
    """
    generator = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    encoder = copy.deepcopy(start) if start is not None else Encoder(sizes, images.shape[-1])
    encoder = encoder.float().train().requires_grad_(True)
    targets = torch.from_numpy(normalise(np.asarray(poses_deg, float), np.asarray(rest_pose), np.asarray(half_ranges))).float()
    pictures = torch.from_numpy(np.ascontiguousarray(images, np.float32))
    order = torch.randperm(len(targets), generator=generator)
    held = max(1, int(round(validation_fraction * len(targets))))
    validation, training = order[:held], order[held:]
    optimiser = torch.optim.Adam(encoder.parameters(), lr=lr)
    history, best, best_state = {"train_nll": [], "validation_nll": []}, np.inf, None
    for _ in range(epochs):
        encoder.train()
        losses = []
        for batch in training[torch.randperm(len(training), generator=generator)].split(batch_size):
            loss = gaussian_nll(*encoder(pictures[batch]), targets[batch])
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            losses.append(float(loss.detach()))
        encoder.eval()
        with torch.no_grad():
            held_loss = float(gaussian_nll(*encoder(pictures[validation]), targets[validation]))
        history["train_nll"].append(float(np.mean(losses)))
        history["validation_nll"].append(held_loss)
        if held_loss < best:
            best, best_state = held_loss, copy.deepcopy(encoder.state_dict())
        if progress:
            progress(len(history["train_nll"]), epochs, held_loss)
    encoder.load_state_dict(best_state)
    return encoder.eval().requires_grad_(False), history


def save_encoder(path, model: PoseModel, sizes, resolution: int) -> None:
    """Write ``model`` to ``path`` (torch's format, tensors and plain data only), via a temporary file."""
    payload = {"format": FORMAT, "state": model.encoder.state_dict(), "sizes": sizes_dict(sizes),
               "resolution": int(resolution), "rest_pose": model.rest_pose.tolist(),
               "half_ranges": model.half_ranges.tolist(), "scale": model.scale.tolist(), "metadata": model.metadata}
    temporary = f"{path}.tmp{os.getpid()}"
    torch.save(payload, temporary)
    os.replace(temporary, path)


def load_encoder(path) -> PoseModel:
    """The :class:`PoseModel` saved at ``path`` (weights_only: no code runs); ComponentError if unusable."""
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError, ValueError) as error:
        raise ComponentError(f"pose encoder {path}: cannot be read ({error})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ComponentError(f"pose encoder {path}: not a pose-encoder checkpoint ({FORMAT})")
    encoder = Encoder(sizes_from_dict(payload["sizes"]), payload["resolution"])
    encoder.load_state_dict(payload["state"])
    return PoseModel(encoder, payload["rest_pose"], payload["half_ranges"], payload["scale"],
                     {**payload["metadata"], "resolution": payload["resolution"]})


class PoseEncoder(Component):
    """Pose-encoder component: the image in; the seen arm's angles and their calibrated variance out.

    The network's convolutions run once per distinct image (``share``): trials showing the same picture share
    them (:func:`~rhi.components.vision.image_sharing.distinct`), and what they gave is kept for the next step or
    batch that shows it (one store per process, :data:`STORE_MB`); the dense layers run once per distinct image
    too (at least :data:`DENSE_ROWS` rows), so a cell of a cohort, whose participants see one picture, costs one
    picture's network a step. The outputs are the unshared computation's bit for bit wherever the network gives
    each image the same numbers in a batch of any size >= :data:`MIN_ROWS` (convolutions) and >=
    :data:`DENSE_ROWS` (dense layers): torch convolves a batch of one, and multiplies fewer than four rows, another
    way. That is checked on each run's first images against the whole
    batch's forward pass; where it fails the component runs unshared. ``evaluated`` counts the images the
    convolutions ran on.
    """

    def __init__(self, model: PoseModel, name: str = "pose_encoder", resolution: int | None = None,
                 threads: int | None = None, share: bool = True):
        trained = model.metadata.get("resolution")
        if resolution is not None and trained is not None and trained != resolution:
            raise ComponentError(f"{name}: the pose encoder was trained at {trained} px, the camera renders "
                                 f"{resolution} px")
        self.model, self.threads, self.share = model, threads or available_cores(), share
        self.sharing, self.evaluated, self._key = False, 0, ()
        side = resolution or trained
        super().__init__(name, [
            Variable("image", "input", "Array", shape=(side, side), element="float32", start=None, unit="1",
                     description="s_v: the camera image, grayscale in [0, 1]"),
            Variable("pose", "output", "Array", shape=(2,), start=None, unit="deg", depends_on=("image",),
                     description="x_v: the seen arm's joint angles (shoulder, elbow)"),
            Variable("pose_variance", "output", "Array", shape=(2,), start=None, unit="deg2",
                     depends_on=("image",), description="calibrated variance of x_v, per joint"),
        ])

    def initialize(self):
        """Set torch's threads, check the shared path on the initial ``image`` and publish its pose."""
        torch.set_num_threads(self.threads)
        # the features depend on the weights and, through the kernels' split of work, on the thread count
        self._key = (weights_key(self.model.encoder), torch.get_num_threads())
        self.sharing, self.evaluated = self.share and self.batch_size >= MIN_ROWS, 0
        if self.sharing:
            self._check_finite()
            whole, shared = self.model(self.values["image"]), self._shared()
            self.sharing = all(np.array_equal(a, b) for a, b in zip(whole, shared))
        self._update()

    def step(self, t, h):
        """Publish ``pose`` (B, 2) deg and ``pose_variance`` (B, 2) deg² of the current ``image``; StepFailure if the
        image is not finite.

        Parameters
        ----------
        t, h : float
            The step's start and size, s (unused: the outputs follow the current inputs).
        """
        self._update()

    def _check_finite(self):
        image = self.values["image"]
        if len(image) > 1 and image.strides[0] == 0:  # one picture broadcast to the batch: check it once
            image = image[:1]
        if not np.all(np.isfinite(image)):
            raise StepFailure(f"{self.name}: the image is not finite")

    def _update(self):
        self._check_finite()
        self.values["pose"], self.values["pose_variance"] = (self._shared() if self.sharing
                                                             else self.model(self.values["image"]))

    def _shared(self) -> tuple[np.ndarray, np.ndarray]:
        """The outputs with the convolutions run once per distinct image not in the store and the dense layers
        once per distinct image, gathered to every trial."""
        image = self.values["image"]
        first, inverse = distinct(image)
        keys = [(*self._key, digest(image[b])) for b in first]
        features = [STORE.get(key) for key in keys]
        missing = [n for n, found in enumerate(features) if found is None]
        if missing:
            rows = image[first[missing]]
            if len(rows) < MIN_ROWS:  # a batch of one runs another kernel: pad with a copy, dropped after
                rows = np.concatenate([rows, np.repeat(rows[-1:], MIN_ROWS - len(rows), axis=0)])
            computed = self.model.features(rows)
            for n, row in zip(missing, computed):
                features[n] = row.copy()  # its own memory: the store counts what it keeps
                STORE.put(keys[n], features[n])
            self.evaluated += len(missing)
        rows = np.stack(features)
        if len(rows) < DENSE_ROWS:  # padded with copies, dropped after
            rows = np.concatenate([rows, np.repeat(rows[-1:], DENSE_ROWS - len(rows), axis=0)])
        angles, variance = self.model.from_features(rows)
        return angles[inverse], variance[inverse]
