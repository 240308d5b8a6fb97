"""The paper's two visual generative models, sharing one decoder definition.

The decoder g maps the belief mu, normalised to [-1, 1] over the training ranges, to
a grayscale image (docs/design.md "Visual decoders")::

    Linear(2 -> hidden), Linear(hidden -> C0 * s * s), reshape to (C0, s, s),
    per stage: ConvTranspose(k4, s2, p1) + Conv(k3, s1, p1), ReLU after each,
    ConvTranspose(k4, s2, p1) to one channel, sigmoid.

With the ``paper`` preset (hidden 1024, stage channels 128, 64, 32, 16) this is the
paper's ConvDecoder, 8x8 -> 256x256. The start size s is resolution / 2**(stages + 1),
so one preset serves any resolution that is a power-of-two multiple of it.

The VAE is a convolutional encoder (Conv(k3) + 2x2 max-pool + ReLU stages mirroring the
decoder, then Linear -> ReLU -> Linear) to a 2-D latent mean and log-variance, plus
the same decoder. Its KL term pulls the latent toward the true normalised joint
angles, so the latent space is joint space and only the decoder is used afterwards.

Example::

    net = build("conv", "default", resolution=64)
    images = net.decoder(torch.zeros(5, 2))      # (5, 64, 64) in [0, 1]
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from ..component import ComponentError

KINDS = ("conv", "vae")


@dataclass(frozen=True)
class Preset:
    """Sizes of one decoder (and of its VAE encoder, which mirrors it).

    hidden: width of the first fully connected layer.
    channels: output channels of each up-sampling stage; the first is also the
        channel count of the initial s x s map.
    resolution: the image size the preset was designed for (the default).
    """

    hidden: int
    channels: tuple[int, ...]
    resolution: int

    def start_size(self, resolution: int) -> int:
        """Side of the initial feature map; ComponentError if ``resolution`` does not fit."""
        factor = 2 ** (len(self.channels) + 1)
        if not isinstance(resolution, int) or resolution < factor or resolution % factor:
            raise ComponentError(f"resolution = {resolution!r} does not fit this decoder: it must be a "
                                 f"positive multiple of {factor} (2 ** (stages + 1))")
        return resolution // factor

    @property
    def encoder_channels(self) -> tuple[int, ...]:
        """The encoder's conv stages: the decoder's channels reversed, the first repeated."""
        return (self.channels[-1],) + tuple(reversed(self.channels))


PRESETS = {
    # The paper's ConvDecoder at 256x256 (docs/design.md); trains on a 2-core CPU with channels-last layout.
    "paper": Preset(hidden=1024, channels=(128, 64, 32, 16), resolution=256),
    # Sized to train in a few minutes on a 2-core CPU at 64x64: 4x4 -> 64x64.
    "default": Preset(hidden=256, channels=(32, 16, 8), resolution=64),
    # For tests: trains in seconds at 16x16 or 32x32.
    "tiny": Preset(hidden=64, channels=(16, 8), resolution=16),
}


def preset(name: str) -> Preset:
    """The :class:`Preset` named ``name`` (a key of :data:`PRESETS`); ComponentError if there is none."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ComponentError(f"preset = {name!r} is unknown; choose one of {', '.join(PRESETS)}") from None


class ConvDecoder(nn.Module):
    """g: normalised joint angles (B, 2) -> image (B, res, res) in [0, 1]."""

    def __init__(self, sizes: Preset, resolution: int):
        super().__init__()
        self.start = sizes.start_size(resolution)
        self.start_channels = sizes.channels[0]
        self.dense = nn.Sequential(
            nn.Linear(2, sizes.hidden), nn.ReLU(),
            nn.Linear(sizes.hidden, self.start_channels * self.start ** 2), nn.ReLU())
        layers, previous = [], self.start_channels
        for channels in sizes.channels:
            layers += [nn.ConvTranspose2d(previous, channels, 4, 2, 1), nn.ReLU(),
                       nn.Conv2d(channels, channels, 3, 1, 1), nn.ReLU()]
            previous = channels
        layers += [nn.ConvTranspose2d(previous, 1, 4, 2, 1), nn.Sigmoid()]
        self.convolutions = nn.Sequential(*layers)

    def forward(self, mu_normalised: torch.Tensor) -> torch.Tensor:
        """g(mu): the images the normalised joint angles predict.

        Parameters
        ----------
        mu_normalised : torch.Tensor
            (B, 2): joint angles normalised to [-1, 1] over the training ranges (:func:`normalise`).

        Returns
        -------
        torch.Tensor
            (B, res, res) in [0, 1].
        """
        features = self.dense(mu_normalised).view(-1, self.start_channels, self.start, self.start)
        return self.convolutions(features)[:, 0]


class Encoder(nn.Module):
    """q: image (B, res, res) -> latent mean and log-variance, each (B, 2), normalised units."""

    def __init__(self, sizes: Preset, resolution: int):
        super().__init__()
        start = sizes.start_size(resolution)
        layers, previous = [], 1
        for channels in sizes.encoder_channels:  # len(channels) + 1 pools: resolution -> start
            # Pooled before the ReLU: relu(max(x)) = max(relu(x)) exactly (ReLU is monotonic), and the
            # gradients are the same too, with the ReLU on a quarter of the pixels (at 256 x 256 the full-size
            # ReLU of the first stage was a large part of the VAE's training step, docs/decoders.md).
            layers += [nn.Conv2d(previous, channels, 3, 1, 1), nn.MaxPool2d(2), nn.ReLU()]
            previous = channels
        self.convolutions = nn.Sequential(*layers)
        self.dense = nn.Sequential(nn.Flatten(), nn.Linear(previous * start ** 2, sizes.hidden), nn.ReLU(),
                                   nn.Linear(sizes.hidden, 4))

    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """q(mu | image): the latent Gaussian of each image.

        Parameters
        ----------
        images : torch.Tensor
            (B, res, res) in [0, 1].

        Returns
        -------
        mean : torch.Tensor
            (B, 2), in normalised joint-angle units.
        log_variance : torch.Tensor
            (B, 2), of the same units squared.
        """
        out = self.dense(self.convolutions(images[:, None]))
        return out[:, :2], out[:, 2:]


class VisualModel(nn.Module):
    """A trained or trainable model: ``decoder`` always, ``encoder`` for the VAE only."""

    def __init__(self, kind: str, sizes: Preset, resolution: int):
        super().__init__()
        if kind not in KINDS:
            raise ComponentError(f"decoder = {kind!r} is unknown; choose one of {', '.join(KINDS)}")
        self.kind = kind
        self.decoder = ConvDecoder(sizes, resolution)
        self.encoder = Encoder(sizes, resolution) if kind == "vae" else None


def build(kind: str, preset_name: str, resolution: int | None = None, sizes: Preset | None = None) -> VisualModel:
    """A float32 model of ``kind`` (conv, vae) with the named preset's sizes (or explicit ``sizes``)."""
    sizes = sizes or preset(preset_name)
    return VisualModel(kind, sizes, sizes.resolution if resolution is None else resolution).float()


def sizes_dict(sizes: Preset) -> dict:
    """The preset as JSON-able data, for checkpoint metadata."""
    data = asdict(sizes)
    data["channels"] = list(sizes.channels)
    return data


def sizes_from_dict(data: dict) -> Preset:
    """The :class:`Preset` of :func:`sizes_dict`'s data (a checkpoint's metadata)."""
    return Preset(hidden=int(data["hidden"]), channels=tuple(int(c) for c in data["channels"]),
                  resolution=int(data["resolution"]))


def normalise(mu_deg, rest_pose, half_ranges):
    """Joint angles (deg) -> decoder input: -1 and +1 at rest -/+ half-range, per joint.

    The one definition of the input normalisation, used in training and in the
    component (whose Jacobian goes through it by the chain rule).
    """
    return (mu_deg - rest_pose) / half_ranges
