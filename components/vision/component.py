"""The visual decoder as a co-simulation component.

Each step, for the whole batch in one decoder call, it predicts the image from the
belief mu, g(mu), differentiates it with forward-mode AD, J = dg/dmu (per degree,
through the input normalisation), and returns the visual term of the paper's eq. 6
(without gamma, which the brain applies)::

    visual_drive = J^T (s_v - g(mu)) * (256*256 / (H*W)) / visual_variance

Visual variance is per pixel, expressed at the reference resolution 256x256: the
factor 256*256/(H*W) makes the drive the same at any resolution (a sum over H*W
pixels of a smooth image scales with H*W), so a value means what the released
agent's 3000 meant at 256x256.

Example::

    decoder = Decoder("conv.pt", resolution=64, rest_pose=kinematics.REST_POSE)
    images = jacobian_images(decoder.model, np.array([[147.7, -91.2]]))   # (1, 2, 64, 64)
"""
from __future__ import annotations

import copy
import os

import numpy as np
import torch
from torch.autograd import forward_ad

from ..component import Component, ComponentError, StepFailure
from ..variables import Variable
from .checkpoint import check_matches, load
from .networks import normalise

REFERENCE_PIXELS = 256 * 256
# Calibrated at the 256x256 reference with this project's camera and decoders (docs/results.md, "Calibrating
# the visual variance"), the value master/config/defaults.toml uses; the released agent's 3000 was for its own images.
DEFAULT_VISUAL_VARIANCE = 20.0
from .limits import MIN_VISUAL_VARIANCE  # noqa: E402: the decoder's visual_variance range


def available_cores() -> int:
    """Torch threads to use: OMP_NUM_THREADS when set (Dask workers set it to 1), else the usable cores."""
    requested = os.environ.get("OMP_NUM_THREADS", "")
    if requested.isdigit() and int(requested) > 0:
        return int(requested)
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


DEVICES = ("auto", "cpu", "cuda")


def resolve_device(name: str) -> str:
    """``auto`` -> ``cuda`` when torch sees a CUDA GPU, else ``cpu``; ``cpu`` as is; ``cuda`` (or ``cuda:N``) only
    when torch sees that GPU, else one ComponentError saying why and what to use instead."""
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cpu":
        return "cpu"
    if name == "cuda" or (name.startswith("cuda:") and name[5:].isdigit()):
        if not torch.cuda.is_available():
            build = "a CPU-only build" if torch.version.cuda is None else f"built for CUDA {torch.version.cuda}"
            raise ComponentError(f"device {name}: torch {torch.__version__} ({build}) sees no CUDA GPU here; "
                                 "use --device cpu or auto (docs/configuration.md: installing a CUDA build of torch)")
        if name != "cuda" and int(name[5:]) >= torch.cuda.device_count():
            raise ComponentError(f"device {name}: torch sees {torch.cuda.device_count()} CUDA GPU(s) (cuda:0 ...)")
        return name
    raise ComponentError(f"device {name!r} is unknown; choose one of {', '.join(DEVICES)}")


class GenerativeModel:
    """g(mu): the trained decoder behind the training normalisation; degrees in, image out.

    decoder: a module mapping normalised angles (B, 2) to images (B, R, R).
    rest_pose, half_ranges: the training ranges (deg), where the input is 0 and +-1.
    """

    def __init__(self, decoder: torch.nn.Module, rest_pose, half_ranges, metadata: dict | None = None):
        self.decoder = decoder.float().eval().requires_grad_(False)
        self.rest_pose = np.array(rest_pose, dtype=np.float64)      # deg, as trained
        self.half_ranges = np.array(half_ranges, dtype=np.float64)  # deg
        self.device = next(self.decoder.parameters(), torch.empty(0)).device
        self._rest = torch.from_numpy(self.rest_pose).float().to(self.device)
        self._half = torch.from_numpy(self.half_ranges).float().to(self.device)
        self.metadata = dict(metadata or {})
        with torch.no_grad():
            self.resolution = int(self(self._rest[None]).shape[-1])

    @classmethod
    def from_checkpoint(cls, path, resolution=None, rest_pose=None, half_ranges=None) -> "GenerativeModel":
        """Load ``path``; CheckpointError if it is unusable or trained for another camera or body."""
        model, metadata = load(path, resolution, rest_pose, half_ranges)
        return cls(model.decoder, metadata["rest_pose"], metadata["half_ranges"], metadata)

    def on(self, device: str) -> "GenerativeModel":
        """This model with its decoder on ``device`` ("cpu", "cuda"): itself if it is there, else a copy."""
        target = torch.device(device)
        if target.type == self.device.type and target.index in (None, self.device.index):
            return self
        return GenerativeModel(copy.deepcopy(self.decoder).to(device), self.rest_pose, self.half_ranges,
                               self.metadata)

    def __call__(self, mu_deg: torch.Tensor) -> torch.Tensor:
        """g(mu) for mu (B, 2) float32 degrees: images (B, R, R) in [0, 1], on the decoder's device."""
        return self.decoder(normalise(mu_deg.to(self.device), self._rest, self._half))

    def predict_with_jacobian(self, mu_deg: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """g(mu) (B, R, R) and J = dg/dmu (B, 2, R, R) in 1/deg, by forward-mode AD.

        One JVP per joint with the same unit tangent for every trial: trials are
        independent (no batch coupling in the decoder), so each gives one Jacobian
        column for the whole batch, and the first also gives the prediction. Dual tensors
        (torch.autograd.forward_ad) give torch.func.jvp's results bitwise and skip its transform
        machinery, which costs time at small images (at large ones the convolutions dominate).
        """
        columns, mu_deg = [], mu_deg.to(self.device)
        with forward_ad.dual_level():
            for joint in range(2):
                tangent = torch.zeros_like(mu_deg)
                tangent[:, joint] = 1.0
                prediction, column = forward_ad.unpack_dual(self(forward_ad.make_dual(mu_deg, tangent)))
                columns.append(column)
        return prediction, torch.stack(columns, dim=1)


def jacobian_images(model: GenerativeModel, mu_deg) -> np.ndarray:
    """The two Jacobian images dg/d(shoulder), dg/d(elbow) per belief: (B, 2, R, R) float32, 1/deg."""
    mu = torch.as_tensor(np.asarray(mu_deg, dtype=np.float32).reshape(-1, 2))
    with torch.no_grad():
        return model.predict_with_jacobian(mu)[1].numpy()


def resolution_weight(height: int, width: int) -> float:
    """256*256 / (H*W): makes a per-pixel variance mean the same at any resolution."""
    return REFERENCE_PIXELS / (height * width)


def visual_drive(jacobian: torch.Tensor, error: torch.Tensor, precision: torch.Tensor) -> torch.Tensor:
    """Visual term of eq. 6 without gamma: J^T Sigma_v^-1 e_v, (B, 2).

    jacobian (B, 2, R, R); error e_v = s_v - g(mu) (B, R, R) (eq. 4); precision (B,):
    resolution weight / visual variance.
    """
    return torch.einsum("bkhw,bhw->bk", jacobian, error) * precision[:, None]


def visual_error(squared_error: torch.Tensor, precision: torch.Tensor) -> torch.Tensor:
    """The free energy's visual term without gamma: 1/2 e_v^T Sigma_v^-1 e_v, (B,).

    squared_error: |e_v|^2 = |s_v - g(mu)|^2 summed over the pixels (B,); precision (B,):
    resolution weight / visual variance. Its gradient is minus the visual drive,
    d/dmu = -J^T Sigma_v^-1 e_v, so the brain's F descends along mu_dot (eq. 6).
    """
    return 0.5 * squared_error * precision


def visual_stiffness(jacobian: torch.Tensor, precision: torch.Tensor) -> torch.Tensor:
    """Largest eigenvalue of J^T Sigma_v^-1 J (B,), 1/s: how fast the drive pulls mu back."""
    return largest_eigenvalue(jacobian_gram(jacobian) * precision[:, None, None])


def jacobian_gram(jacobian: torch.Tensor) -> torch.Tensor:
    """J^T J (B, 2, 2) of Jacobians (B, 2, R, R)."""
    return torch.einsum("bkhw,blhw->bkl", jacobian, jacobian)


def largest_eigenvalue(gram: torch.Tensor) -> torch.Tensor:
    """Largest eigenvalue (B,) of symmetric 2 x 2 matrices (B, 2, 2), in closed form."""
    a, b, d = gram[:, 0, 0], gram[:, 0, 1], gram[:, 1, 1]
    return 0.5 * (a + d) + torch.sqrt((0.5 * (a - d)).square() + b.square())


class Decoder(Component):
    """Visual decoder component: belief and image in, visual drive and prediction out.

    checkpoint: a path (loaded safely) or a :class:`GenerativeModel`.
    resolution, rest_pose, half_ranges: what the camera renders and the body rests at;
        when given, a checkpoint trained for anything else is rejected (CheckpointError).
    threads: torch threads for the step (default: the cores this process may use).
    device: where the decoder runs ("cpu", "cuda"; :func:`resolve_device` resolves "auto"); the inputs and
        outputs stay NumPy arrays on the CPU.
    """

    def __init__(self, checkpoint, name: str = "decoder", resolution: int | None = None, rest_pose=None,
                 half_ranges=None, threads: int | None = None, device: str = "cpu"):
        if isinstance(checkpoint, GenerativeModel):
            self.model = checkpoint
            trained = {"resolution": checkpoint.resolution, "rest_pose": checkpoint.rest_pose.tolist(),
                       "half_ranges": checkpoint.half_ranges.tolist()}
            check_matches(f"{name} (an in-memory decoder)", trained, resolution, rest_pose, half_ranges)
        else:
            self.model = GenerativeModel.from_checkpoint(checkpoint, resolution, rest_pose, half_ranges)
        self.model = self.model.on(device)
        self.threads = threads or available_cores()
        image = (self.model.resolution, self.model.resolution)
        super().__init__(name, [
            Variable("visual_variance", "parameter", start=DEFAULT_VISUAL_VARIANCE, unit="1", min=MIN_VISUAL_VARIANCE,
                     description="Sigma_v: visual variance per pixel, at the 256x256 reference resolution"),
            Variable("mu", "input", "Array", shape=(2,), start=self.model.rest_pose, unit="deg",
                     description="belief mu: shoulder, elbow joint angles"),
            Variable("image", "input", "Array", shape=image, element="float32", start=None, unit="1",
                     description="s_v: the camera image, grayscale in [0, 1]"),
            Variable("visual_drive", "output", "Array", shape=(2,), start=None, unit="deg/s",
                     description="J^T (s_v - g(mu)) * 256^2/(H W) / visual_variance (eq. 6, without gamma)",
                     depends_on=("mu", "image")),
            Variable("prediction", "output", "Array", shape=image, element="float32", start=None, unit="1",
                     description="g(mu): the image the belief predicts", depends_on=("mu",)),
            Variable("visual_error", "output", start=None, unit="1", min=0.0,
                     description="1/2 (s_v - g)^T (s_v - g) * 256^2/(H W) / visual_variance: F's visual "
                                 "term without gamma",
                     depends_on=("mu", "image")),
            Variable("visual_stiffness", "output", start=None, unit="1/s", min=0.0,
                     description="largest eigenvalue of J^T J * 256^2/(H W) / visual_variance",
                     depends_on=("mu",)),
        ])

    def initialize(self):
        """Set torch's threads and publish the outputs of the initial ``mu`` and ``image``."""
        torch.set_num_threads(self.threads)
        self._update()

    def step(self, t, h):
        """Publish ``visual_drive`` (B, 2) deg/s, ``visual_error`` (B,), ``visual_stiffness`` (B,) 1/s and
        ``prediction`` (B, res, res) of the current ``mu`` and ``image``; StepFailure if ``mu`` is not finite.

        Parameters
        ----------
        t, h : float
            The step's start and size, s (unused: the outputs follow the current inputs).
        """
        self._update()

    def _checked_inputs(self):
        """mu (B, 2) float64, the image as float32 C-contiguous numpy, and the per-trial precision tensor."""
        mu = np.asarray(self.values["mu"], dtype=np.float64)
        if not np.all(np.isfinite(mu)):
            trial = int(np.argwhere(~np.isfinite(mu))[0][0])
            raise StepFailure(f"belief mu of trial {trial} is not finite: {mu[trial].tolist()}")
        image = self.values["image"]
        if image.dtype != np.float32 or not image.flags.c_contiguous:
            image = np.ascontiguousarray(image, dtype=np.float32)
        precision = torch.from_numpy(resolution_weight(*image.shape[1:]) / self.values["visual_variance"]).float()
        return mu, image, precision

    def _update(self):
        mu, image, precision = self._checked_inputs()
        device = self.model.device
        sensed = torch.from_numpy(image).to(device)  # on the CPU: shares memory, no copy of the images
        precision = precision.to(device)
        with torch.no_grad():
            prediction, jacobian = self.model.predict_with_jacobian(torch.from_numpy(mu.astype(np.float32)))
            error = sensed - prediction
            self.values["visual_drive"] = visual_drive(jacobian, error, precision).double().cpu().numpy()
            self.values["visual_error"] = visual_error(error.square().sum(dim=(1, 2)),
                                                       precision).double().cpu().numpy()
            self.values["visual_stiffness"] = visual_stiffness(jacobian, precision).double().cpu().numpy()
        self.values["prediction"] = prediction.cpu().numpy()  # a new tensor each step, shared with numpy
