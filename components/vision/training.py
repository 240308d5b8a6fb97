"""Training a visual decoder on (joint angles, image) pairs: seeded and deterministic.

The ConvDecoder minimises the image MSE of g(normalised angles). The VAE minimises
image MSE of g(z), z ~ q(z | image) (reparameterised), plus ``kl_weight`` times the
KL divergence from q to a narrow Gaussian (``prior_variance``, 0.001) centred on the
true normalised angles, so that the latent is joint space (docs/design.md).

The data are split once (seeded) into training and validation; the learning rate
follows a cosine from ``lr`` down to ``lr * final_lr_fraction``; training stops early
when the validation loss has not improved for ``patience`` epochs, and the best
epoch's weights are kept. With the same data, settings, device and thread count, two
runs give bitwise identical weights.

For large images (the paper preset at 256 x 256) three settings make a step faster on a
CPU, at the price of other float rounding than the plain path (docs/decoders.md,
"The paper's scale"): ``channels_last`` (the convolutions in channels-last layout, oneDNN's fast
kernels), ``fused_adam`` (one fused optimiser step), and ``stop_hand_error_cm`` (stop
as soon as a caller's ``check`` says the decoder is good enough, so that the epochs are
an upper bound). ``device`` runs the training on a GPU (``cuda``); the batches and the
VAE's noise are drawn on the CPU either way, so a GPU gives the CPU's results up to
float rounding.

Example::

    model, report = train("conv", poses, images, rest_pose, half_ranges, TrainSettings(epochs=5))
"""
from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields

import numpy as np
import torch
from tqdm import tqdm

from ..component import ComponentError
from .component import available_cores
from .networks import KINDS, PRESETS, VisualModel, build, normalise, preset, sizes_dict


@dataclass(frozen=True)
class TrainSettings:
    """Defaults sized for the default preset on a 2-core CPU (a few minutes per decoder)."""

    samples: int = 3000             # rendered (angles, image) pairs, training + validation
    epochs: int = 20                # at most; early stopping may end sooner
    batch_size: int = 32
    lr: float = 3e-3                # Adam, peak learning rate
    final_lr_fraction: float = 0.02  # the cosine schedule ends at lr * this
    patience: int = 5               # epochs without a better validation loss before stopping
    seed: int = 0                   # data, split, initial weights, batches, VAE noise
    preset: str = "default"         # network sizes: default, paper, tiny
    resolution: int = 64            # image side, px (the camera's)
    validation_fraction: float = 0.1
    kl_weight: float = 1.0          # VAE only: weight of the KL term against the per-pixel MSE
    prior_variance: float = 0.001   # VAE only: variance of the prior around the true normalised angles
    quality_poses: int = 100        # held-out poses for the hand-error measure after training (0: skip)
    threads: int = 1                # torch threads (0: every core this process may use); a run is bitwise
                                    # reproducible for a fixed count, so the default is one count everywhere
    channels_last: bool = False     # convolutions in channels-last layout (faster on CPU at 256 x 256)
    fused_adam: bool = False        # the fused Adam step (faster for large networks)
    stop_hand_error_cm: float = 0.0  # stop when the caller's check (the hand error read off held-out
                                     # poses, cm) is at most this after an epoch; 0: never

    def __post_init__(self):
        positive_ints = ("samples", "epochs", "batch_size", "patience", "resolution")
        for name in positive_ints:
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ComponentError(f"train setting {name} = {value!r} must be a positive integer")
        for name in ("seed", "quality_poses", "threads"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ComponentError(f"train setting {name} = {value!r} must be a non-negative integer")
        for name, low, high in (("lr", 0.0, 1.0), ("final_lr_fraction", 0.0, 1.0), ("kl_weight", 0.0, 1e6),
                                ("prior_variance", 0.0, 1e3), ("validation_fraction", 0.0, 0.9)):
            value = getattr(self, name)
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            if not ok or not (low < value <= high or (name in ("final_lr_fraction", "kl_weight") and value == 0)):
                raise ComponentError(f"train setting {name} = {value!r} must be a number in ({low}, {high}]")
        for name in ("channels_last", "fused_adam"):
            if not isinstance(getattr(self, name), bool):
                raise ComponentError(f"train setting {name} = {getattr(self, name)!r} must be true or false")
        value = self.stop_hand_error_cm
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
            raise ComponentError(f"train setting stop_hand_error_cm = {value!r} must be a number >= 0 (0: never)")
        if self.preset not in PRESETS:
            raise ComponentError(f"train setting preset = {self.preset!r} is unknown; choose one of "
                                 f"{', '.join(PRESETS)}")
        preset(self.preset).start_size(self.resolution)  # the resolution must fit the preset
        if self.samples < 2 or validation_count(self.samples, self.validation_fraction) >= self.samples:
            raise ComponentError(f"train setting samples = {self.samples} leaves no training data")

    @classmethod
    def names(cls) -> list[str]:
        """The settings' names, in declaration order."""
        return [f.name for f in fields(cls)]

    def as_dict(self) -> dict:
        """Every setting by name, as a plain dict."""
        return asdict(self)

    def identity(self) -> dict:
        """The settings that name a trained decoder (its cache key, its checkpoint's metadata): every field,
        but those of :data:`LATER_FIELDS` at their defaults, so that a decoder trained before they existed
        keeps its name and its checkpoint's bytes."""
        return {key: value for key, value in asdict(self).items()
                if key not in LATER_FIELDS or value != LATER_FIELDS[key]}


# Fields added after decoders were first cached by a hash of their settings, with their defaults.
LATER_FIELDS = {"channels_last": False, "fused_adam": False, "stop_hand_error_cm": 0.0}


def validation_count(samples: int, fraction: float) -> int:
    """The samples held out for validation: ``round(samples * fraction)``, at least 1."""
    return max(1, round(samples * fraction))


def kl_to_prior(mean, log_variance, target, prior_variance: float) -> torch.Tensor:
    """KL( N(mean, exp(log_variance)) || N(target, prior_variance) ), summed over the 2 latents, (B,)."""
    variance = log_variance.exp()
    return 0.5 * ((variance + (mean - target).square()) / prior_variance - 1.0
                  - log_variance + math.log(prior_variance)).sum(dim=1)


def start_at_mean_image(model: VisualModel, images: torch.Tensor) -> None:
    """Set the output bias to logit(mean pixel): training starts at the mean brightness instead of
    0.5 everywhere, whose large first gradients saturate the sigmoid and kill the ReLUs (the arm
    covers a few per cent of a dark image)."""
    mean = float(images.mean().clamp(1e-4, 1 - 1e-4))
    with torch.no_grad():
        model.decoder.convolutions[-2].bias.fill_(math.log(mean / (1 - mean)))


def batch_loss(model: VisualModel, inputs, images, settings: TrainSettings, generator=None):
    """The training objective on one batch (mean over it); a ``generator`` samples the VAE latent,
    without one the VAE decodes its latent mean (validation)."""
    if model.kind == "conv":
        return (model.decoder(inputs) - images).square().mean()
    mean, log_variance = model.encoder(images)
    latent = mean
    if generator is not None:  # drawn on the generator's device (the CPU), then moved: the same noise anywhere
        noise = torch.randn(mean.shape, generator=generator).to(mean.device)
        latent = mean + (0.5 * log_variance).exp() * noise
    reconstruction = (model.decoder(latent) - images).square().mean()
    kl = kl_to_prior(mean, log_variance, inputs, settings.prior_variance).mean()
    return reconstruction + settings.kl_weight * kl


def evaluate(model: VisualModel, inputs, images, settings: TrainSettings, chunk: int = 256) -> dict:
    """Validation loss (the objective, deterministic) and the decoder's image MSE at the true angles,
    ``chunk`` samples at a time, fewer for images larger than 64 x 64 (bounded memory)."""
    chunk = max(1, min(chunk, chunk * 64 * 64 // images[0].numel()))
    loss = mse = 0.0
    with torch.no_grad():
        for start in range(0, len(inputs), chunk):
            x, y = inputs[start:start + chunk], images[start:start + chunk]
            loss += float(batch_loss(model, x, y, settings)) * len(x)
            mse += float((model.decoder(x) - y).square().mean()) * len(x)
    return {"loss": loss / len(inputs), "mse": mse / len(inputs)}


def train(kind: str, poses_deg: np.ndarray, images: np.ndarray, rest_pose, half_ranges,
          settings: TrainSettings = TrainSettings(), progress: bool | Callable = True, device: str = "cpu",
          check: Callable[[torch.nn.Module], float] | None = None) -> tuple[VisualModel, dict]:
    """Train a decoder of ``kind`` (conv, vae) on poses (N, 2) deg and images (N, R, R) float32.

    device: where the network runs ("cpu", "cuda"; see :func:`resolve_device`).
    progress: a tqdm bar of the epochs on stderr (False: none; a callable taking tqdm's arguments: its bar).
    check: given the decoder after each epoch (eval mode; it must not change it), the hand error
        in cm; training stops once it is at most ``settings.stop_hand_error_cm`` (needed when that is > 0).

    Returns the model on the CPU with its best validation epoch's weights (eval mode) and a
    report: validation_mse, validation_loss, epochs_run, best_epoch, seconds, history.
    """
    if kind not in KINDS:
        raise ComponentError(f"decoder = {kind!r} is unknown; choose one of {', '.join(KINDS)}")
    if images.ndim != 3 or images.shape[1:] != (settings.resolution,) * 2 or len(images) != len(poses_deg):
        raise ComponentError(f"training images of shape {images.shape} do not match {len(poses_deg)} poses "
                             f"at resolution {settings.resolution}")
    if settings.stop_hand_error_cm and check is None:
        raise ComponentError("train setting stop_hand_error_cm needs a check of the hand error (rhi train has one)")
    started = time.perf_counter()
    torch.set_num_threads(settings.threads or available_cores())
    torch.manual_seed(settings.seed)
    generator = torch.Generator().manual_seed(settings.seed)  # on the CPU whatever the device
    model = build(kind, settings.preset, settings.resolution)  # initial weights drawn on the CPU
    if settings.channels_last:
        model = model.to(memory_format=torch.channels_last)
    model = model.to(device)
    inputs = normalise(torch.as_tensor(poses_deg, dtype=torch.float64), torch.tensor(rest_pose, dtype=torch.float64),
                       torch.tensor(half_ranges, dtype=torch.float64)).float().to(device)
    targets = torch.from_numpy(np.ascontiguousarray(images, dtype=np.float32)).to(device)
    order = torch.randperm(len(inputs), generator=generator)
    n_validation = validation_count(len(inputs), settings.validation_fraction)
    validation, training = order[:n_validation], order[n_validation:]
    x_val, y_val = inputs[validation], targets[validation]
    start_at_mean_image(model, targets[training])

    optimiser = torch.optim.Adam(model.parameters(), lr=settings.lr, **({"fused": True} if settings.fused_adam else {}))
    batches_per_epoch = math.ceil(len(training) / settings.batch_size)
    total = settings.epochs * batches_per_epoch
    floor = settings.final_lr_fraction
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimiser, lambda step: floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * min(step, total) / total)))

    best = {"loss": math.inf}
    model.eval()
    initial = evaluate(model, x_val, y_val, settings)
    history = []
    make_bar = progress if callable(progress) else tqdm  # a callable: tqdm's signature, e.g. one for a log file
    bar = make_bar(range(settings.epochs), desc=f"train {kind}", unit="epoch", disable=not progress, leave=True)
    for epoch in bar:
        model.train()
        running = 0.0
        shuffled = training[torch.randperm(len(training), generator=generator)].to(device)
        for start in range(0, len(shuffled), settings.batch_size):
            batch = shuffled[start:start + settings.batch_size]
            loss = batch_loss(model, inputs[batch], targets[batch], settings, generator)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            schedule.step()
            running += loss.item() * len(batch)
        model.eval()
        scores = evaluate(model, x_val, y_val, settings)
        history.append({"epoch": epoch + 1, "train_loss": running / len(training),
                        "validation_loss": scores["loss"], "validation_mse": scores["mse"]})
        if settings.stop_hand_error_cm:
            history[-1]["hand_error_cm"] = float(check(model.decoder))
        history[-1]["seconds"] = time.perf_counter() - started
        if not math.isfinite(scores["loss"]):
            raise ComponentError(f"training diverged at epoch {epoch + 1} (validation loss {scores['loss']}); "
                                 f"lower lr = {settings.lr}")
        if scores["loss"] < best["loss"]:
            best = {"loss": scores["loss"], "mse": scores["mse"], "epoch": epoch + 1,
                    "weights": copy.deepcopy(model.state_dict())}
        bar.set_postfix(train=f"{history[-1]['train_loss']:.2e}", val=f"{scores['loss']:.2e}",
                        lr=f"{schedule.get_last_lr()[0]:.1e}",
                        **({"hand": f"{history[-1]['hand_error_cm']:.3f}cm"} if "hand_error_cm" in history[-1] else {}))
        if epoch + 1 - best["epoch"] >= settings.patience:
            break
        if settings.stop_hand_error_cm and history[-1]["hand_error_cm"] <= settings.stop_hand_error_cm:
            break
    bar.close()
    model.load_state_dict(best["weights"])
    model = model.to("cpu", memory_format=torch.contiguous_format)
    model.eval().requires_grad_(False)
    x_val, y_val = x_val.cpu(), y_val.cpu()
    report = {"validation_mse": best["mse"], "validation_loss": best["loss"], "best_epoch": best["epoch"],
              "initial_validation_loss": initial["loss"], "initial_validation_mse": initial["mse"],
              "epochs_run": len(history), "seconds": time.perf_counter() - started,
              "train_samples": len(training), "validation_samples": n_validation, "history": history}
    if kind == "vae":
        with torch.no_grad():
            mean, _ = model.encoder(y_val)
        report["latent_error_deg"] = ((mean - x_val).abs() * torch.tensor(half_ranges)).mean(0).tolist()
    return model, report


def checkpoint_metadata(kind: str, settings: TrainSettings, rest_pose, half_ranges, data_hash: str,
                        report: dict) -> dict:
    """The JSON metadata stored with a trained decoder (see checkpoint.REQUIRED).

    Nothing of the run's wall time is stored: the same settings give the same checkpoint bytes."""
    return {"kind": kind, "preset": settings.preset, "sizes": sizes_dict(preset(settings.preset)),
            "resolution": settings.resolution, "rest_pose": [float(a) for a in rest_pose],
            "half_ranges": [float(a) for a in half_ranges], "data_hash": data_hash,
            "validation_mse": float(report["validation_mse"]),
            "validation_loss": float(report["validation_loss"]),
            "best_epoch": report["best_epoch"], "epochs_run": report["epochs_run"],
            "settings": settings.identity(), "torch": torch.__version__,
            **({"latent_error_deg": report["latent_error_deg"]} if "latent_error_deg" in report else {}),
            **({"hand_error_checks_cm": [h["hand_error_cm"] for h in report["history"]]}
               if settings.stop_hand_error_cm else {})}
