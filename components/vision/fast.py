"""The fast (linearised) decoder: g(mu) replaced by its tangent between re-linearisations.

Per trial, the component keeps a linearisation point mu0 with g0 = g(mu0) and J0 = dg/dmu(mu0)
(forward-mode JVPs, :meth:`GenerativeModel.predict_with_jacobian`) and predicts

    g(mu) ~ g0 + J0 (mu - mu0),   J(mu) ~ J0,

so a step costs a few passes over J0 instead of a decoder call. A trial is re-linearised
at its current mu when max_j |mu_j - mu0_j| exceeds ``relinearise_tolerance`` (deg); all
trials that need it in one step share one batched decoder call, and identical beliefs (all
trials start at the rest pose) are evaluated once. Tolerance 0 re-linearises every trial
whose mu changed at all: the outputs are then the exact decoder's (to float rounding).

The outputs are those of :class:`~components.vision.component.Decoder`, computed by the same
functions (visual_drive, visual_error, visual_stiffness) on the linearised prediction; the
stiffness is the one of J0.

Example::

    decoder = LinearisedDecoder("conv.pt", relinearise_tolerance=0.01)
    ...simulate as with Decoder...; decoder.relinearisations   # per trial, initialisation included
"""
from __future__ import annotations

import copy

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.autograd import forward_ad

from components.variables import Variable
from components.vision.component import Decoder, GenerativeModel, visual_drive, visual_error, visual_stiffness
from components.vision.networks import ConvDecoder, normalise

DEFAULT_TOLERANCE = 0.01  # deg: final drift within 0.1 % of the exact integrator's (README, bench section)


class DualNumberModel(GenerativeModel):
    """g(mu) whose Jacobian comes from forward-mode AD with dual tensors (torch.autograd.forward_ad).

    The same JVPs as :meth:`GenerativeModel.predict_with_jacobian` (torch.func.jvp), bitwise
    equal results, but several times faster on CPU (measured 3.7 s -> 0.8 s for 60 trials at
    64x64): torch.func's transform machinery is skipped.
    """

    def predict_with_jacobian(self, mu_deg: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        columns = []
        with forward_ad.dual_level():
            for joint in range(2):
                tangent = torch.zeros_like(mu_deg)
                tangent[:, joint] = 1.0
                prediction, column = forward_ad.unpack_dual(self(forward_ad.make_dual(mu_deg, tangent)))
                columns.append(column)
        return prediction, torch.stack(columns, dim=1)


class TangentModel(DualNumberModel):
    """g(mu) and J by forward-mode AD written out layer by layer, for a ConvDecoder (others: dual numbers).

    The tangents of both joints ride together as a batch of 2B through the same layers: Linear,
    Conv2d and ConvTranspose2d without their bias, ReLU and Sigmoid as masks. One primal pass and
    two tangent passes, against the three per joint that PyTorch's convolution JVP runs (it also
    convolves the input with a zero weight tangent): half the FLOPs, the same Jacobian to 1e-6.
    """

    def predict_with_jacobian(self, mu_deg: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        decoder = self.decoder
        if not isinstance(decoder, ConvDecoder):
            return super().predict_with_jacobian(mu_deg)
        batch = len(mu_deg)
        primal = normalise(mu_deg, self._rest, self._half)
        tangent = torch.zeros(2 * batch, 2)  # d(normalised input)/d(joint angle): 1/half-range
        tangent[:batch, 0], tangent[batch:, 1] = 1.0 / self._half[0], 1.0 / self._half[1]
        for layer in decoder.dense:
            primal, tangent = _tangent_step(layer, primal, tangent)
        shape = (decoder.start_channels, decoder.start, decoder.start)
        primal, tangent = primal.view(-1, *shape), tangent.view(-1, *shape)
        for layer in decoder.convolutions:
            primal, tangent = _tangent_step(layer, primal, tangent)
        return primal[:, 0], torch.stack([tangent[:batch, 0], tangent[batch:, 0]], dim=1)


def _tangent_step(layer, primal, tangent):
    """One layer's output and the tangents' (linear layers without bias; activations as derivative masks)."""
    if isinstance(layer, nn.Linear):
        return layer(primal), F.linear(tangent, layer.weight)
    if isinstance(layer, nn.ConvTranspose2d):
        return layer(primal), F.conv_transpose2d(tangent, layer.weight, None, layer.stride, layer.padding,
                                                 layer.output_padding, layer.groups, layer.dilation)
    if isinstance(layer, nn.Conv2d):
        return layer(primal), F.conv2d(tangent, layer.weight, None, layer.stride, layer.padding, layer.dilation,
                                       layer.groups)
    if isinstance(layer, nn.ReLU):
        mask = (primal > 0).to(tangent.dtype)
        return layer(primal), tangent * torch.cat([mask, mask])
    if isinstance(layer, nn.Sigmoid):
        output = torch.sigmoid(primal)
        slope = output * (1 - output)
        return output, tangent * torch.cat([slope, slope])
    raise TypeError(f"no tangent rule for {type(layer).__name__}")


def optimised(model: GenerativeModel) -> TangentModel:
    """A copy of ``model`` with layer-by-layer JVPs and its convolutions in channels-last layout.

    The same function (to float rounding). On CPU, channels-last runs ConvTranspose2d and its
    tangent through oneDNN instead of a generic path (1.3-3x faster at 64x64 and 256x256), and
    the written-out JVP halves the work of the Jacobian (2x faster).
    """
    decoder = copy.deepcopy(model.decoder).to(memory_format=torch.channels_last)
    return TangentModel(decoder, model.rest_pose, model.half_ranges, model.metadata)


class LinearisedDecoder(Decoder):
    """Decoder component with the tangent-linear fast mode; same variables plus relinearise_tolerance.

    checkpoint, name, resolution, rest_pose, half_ranges, threads: as for Decoder.
    relinearise_tolerance: start value of the parameter (deg, >= 0).
    fast_layout: run the decoder through :func:`optimised` (written-out JVPs, channels-last).

    After a run, ``relinearisations`` (B,) counts each trial's linearisations (the initial
    one included) and ``decoder_calls`` the batched decoder calls.
    """

    def __init__(self, checkpoint, name: str = "decoder", relinearise_tolerance: float = DEFAULT_TOLERANCE,
                 resolution: int | None = None, rest_pose=None, half_ranges=None, threads: int | None = None,
                 fast_layout: bool = True):
        super().__init__(checkpoint, name, resolution, rest_pose, half_ranges, threads)
        if fast_layout:
            self.model = optimised(self.model)
        tolerance = Variable("relinearise_tolerance", "parameter", start=relinearise_tolerance, unit="deg", min=0.0,
                             description="re-linearise g when a joint of mu moves more than this from mu0")
        self.variables[tolerance.name] = tolerance
        self.relinearisations = np.zeros(0, dtype=np.int64)
        self.decoder_calls = 0

    def initialize(self):
        torch.set_num_threads(self.threads)
        pixels = self.model.resolution ** 2
        self._mu0 = np.full((self.batch_size, 2), np.nan)  # NaN: never linearised, so every trial is at first
        self._g0 = torch.zeros(self.batch_size, pixels)
        self._jacobian = torch.zeros(self.batch_size, 2, pixels)
        self._stiffness = torch.zeros(self.batch_size)
        self.relinearisations = np.zeros(self.batch_size, dtype=np.int64)
        self.decoder_calls = 0
        self._update()

    def stale(self, mu: np.ndarray) -> np.ndarray:
        """Trials (B,) bool whose belief moved more than the tolerance from their linearisation point."""
        moved = np.abs(mu - self._mu0).max(axis=1)
        return ~(moved <= self.values["relinearise_tolerance"])  # NaN (never linearised) counts as stale

    def relinearise(self, trials: np.ndarray, mu: np.ndarray, precision: torch.Tensor) -> None:
        """g0, J0 and the stiffness at the current mu of ``trials``, in one decoder call over distinct beliefs."""
        points, inverse = np.unique(mu[trials], axis=0, return_inverse=True)
        with torch.no_grad():
            prediction, jacobian = self.model.predict_with_jacobian(torch.from_numpy(points.astype(np.float32)))
        index = torch.from_numpy(trials)
        rows = torch.from_numpy(inverse.reshape(-1))
        self._g0[index] = prediction.reshape(len(points), -1)[rows]
        self._jacobian[index] = jacobian.reshape(len(points), 2, -1)[rows]
        shape = (len(trials), 2, *prediction.shape[1:])
        self._stiffness[index] = visual_stiffness(self._jacobian[index].view(shape), precision[index])
        self._mu0[trials] = mu[trials]
        self.relinearisations[trials] += 1
        self.decoder_calls += 1

    def _update(self):
        mu, image, precision = self._checked_inputs()
        batch, side = image.shape[0], image.shape[1]
        stale = np.flatnonzero(self.stale(mu))
        if len(stale):
            self.relinearise(stale, mu, precision)
        with torch.no_grad():
            step = torch.from_numpy((mu - self._mu0).astype(np.float32))
            prediction = torch.empty(batch, side, side)
            drive, squared = torch.empty(batch, 2), torch.empty(batch)
            sensed = torch.from_numpy(image)
            # On one thread, one trial at a time, so that its J0, g0, prediction and error stay in cache
            # (about 1.3 MB at 256 x 256): 1.5x faster than whole-batch passes, which stream each array
            # from memory again. On more threads, whole-batch passes, which parallelise better.
            chunk = batch if torch.get_num_threads() > 1 else 1
            for start in range(0, batch, chunk):
                part = slice(start, start + chunk)
                # A freshly linearised trial has a step of exactly 0: its prediction is g0 to the bit.
                torch.baddbmm(self._g0[part, None], step[part, None], self._jacobian[part],
                              out=prediction[part].view(-1, 1, side * side))
                error = sensed[part] - prediction[part]
                jacobian = self._jacobian[part].view(-1, 2, side, side)
                drive[part] = visual_drive(jacobian, error, precision[part])
                squared[part] = visual_error(error, precision[part])
            self.values["visual_drive"] = drive.double().numpy()
            self.values["visual_error"] = squared.double().numpy()
            self.values["visual_stiffness"] = self._stiffness.double().numpy()
        self.values["prediction"] = prediction.numpy()
