"""The fast (linearised) decoder: g(mu) replaced by its tangent at a nearby linearisation point.

Each trial keeps a linearisation point mu0, with g0 = g(mu0) and J0 = dg/dmu(mu0) from
forward-mode JVPs (:meth:`GenerativeModel.predict_with_jacobian`), and the decoder predicts

    g(mu) ~ g0 + J0 (mu - mu0),   J(mu) ~ J0.

When mu moves more than ``relinearise_tolerance`` (deg, on either joint) from mu0, the trial
takes a new point: the nearest stored point within the tolerance of its mu if there is
one, else mu itself; either way |mu - mu0| <= tolerance after every step. Points are
shared between trials and kept (up to ``memory_mb``, the least recently used dropped
first), so trials moving along similar paths (the protocol's repetitions of a cell) share
decoder evaluations (measured: 14.7 points per trial instead of 73 at 0.01 deg, five
trials per cell), and all new points of a step are evaluated in one batched call. Tolerance 0 takes a new point every step mu changes: the
outputs are then the exact decoder's (to float rounding).

A step costs one pass over each trial's image and one over each point in use, for
J0^T (s - g0) and |s - g0|^2 per trial; the terms in d = mu - mu0 follow in float64
(:func:`linearised_terms`), scaled by the precision as in :func:`visual_drive` and
:func:`visual_error`.
The prediction output is computed only if read (:class:`~components.component.Deferred`).

Example::

    decoder = LinearisedDecoder("conv.pt", relinearise_tolerance=0.01)
    ...simulate as with Decoder...; decoder.decoder_points   # linearisations the decoder evaluated
"""
from __future__ import annotations

import copy

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.autograd import forward_ad

from components.component import Deferred
from components.variables import Variable
from components.vision.component import Decoder, GenerativeModel, jacobian_gram, largest_eigenvalue
from components.vision.networks import ConvDecoder, normalise

ACTIVATION_BUDGET = 24 * 2**20  # bytes of the largest feature map of one decoder pass: about this CPU's L3 (32 MB)
DEFAULT_TOLERANCE = 0.01  # deg: final drift within 0.1 % of the exact integrator's (measured 0.06 %: README, fast mode)


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

    The primal and the tangents of both joints ride as one batch of 3B (rows: primal, then
    d/d shoulder, then d/d elbow) through each Linear, Conv2d and ConvTranspose2d, run once
    without bias (the bias is added to the primal rows alone); ReLU zeroes all three where
    the primal is not positive, and Sigmoid scales the tangents by its slope. One primal pass
    and two tangent passes, against the three per joint that PyTorch's convolution JVP runs
    (it also convolves the input with a zero weight tangent): half the FLOPs, the same
    Jacobian to 1e-6, and one large convolution call per layer instead of two.
    """

    def predict_with_jacobian(self, mu_deg: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """g (B, R, R) and J (B, 2, R, R), a chunk of trials at a time so that each chunk's largest feature
        map stays within ACTIVATION_BUDGET (measured at 256 x 256, 60 trials: 70 -> 91 GFLOP/s in chunks of 8)."""
        decoder = self.decoder
        if not isinstance(decoder, ConvDecoder):
            return super().predict_with_jacobian(mu_deg)
        chunk = max(1, ACTIVATION_BUDGET // (3 * 4 * largest_feature_map(decoder)))
        if len(mu_deg) <= chunk:
            return self._chunk(mu_deg)
        side = self.resolution
        prediction, jacobian = torch.empty(len(mu_deg), side, side), torch.empty(len(mu_deg), 2, side, side)
        for start in range(0, len(mu_deg), chunk):
            part = slice(start, start + chunk)
            prediction[part], jacobian[part] = self._chunk(mu_deg[part])
        return prediction, jacobian

    def _chunk(self, mu_deg: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        decoder, batch = self.decoder, len(mu_deg)
        rows = torch.zeros(3 * batch, 2)  # tangent rows: d(normalised input)/d(joint angle) = 1/half-range
        rows[:batch] = normalise(mu_deg, self._rest, self._half)
        rows[batch:2 * batch, 0], rows[2 * batch:, 1] = 1.0 / self._half[0], 1.0 / self._half[1]
        for layer in decoder.dense:
            rows = _tangent_step(layer, rows, batch)
        rows = rows.view(-1, decoder.start_channels, decoder.start, decoder.start)
        for layer in decoder.convolutions:
            rows = _tangent_step(layer, rows, batch)
        return rows[:batch, 0], torch.stack([rows[batch:2 * batch, 0], rows[2 * batch:, 0]], dim=1)


def largest_feature_map(decoder: ConvDecoder) -> int:
    """Floats in the largest feature map of one row (primal or tangent) through the decoder's convolutions."""
    channels, side = decoder.start_channels, decoder.start
    largest = channels * side * side
    for layer in decoder.convolutions:
        if isinstance(layer, nn.ConvTranspose2d):
            channels, side = layer.out_channels, 2 * side
        elif isinstance(layer, SubPixelTransposedConv):  # 4 x C channels at the input side, then shuffled
            largest = max(largest, layer.weight.shape[0] * side * side)
            channels, side = layer.weight.shape[0] // 4, 2 * side
        elif isinstance(layer, nn.Conv2d):
            channels = layer.out_channels
        largest = max(largest, channels * side * side)
    return largest


def _tangent_step(layer, rows: torch.Tensor, batch: int) -> torch.Tensor:
    """One layer applied to [primal; tangents] (3B, ...): linear maps without bias, then the bias on the primal."""
    if isinstance(layer, (nn.Linear, nn.Conv2d, nn.ConvTranspose2d, SubPixelTransposedConv)):
        out = _without_bias(layer, rows)
        if layer.bias is not None:
            out[:batch] += layer.bias if out.dim() == 2 else layer.bias.view(-1, 1, 1)
        return out
    split = rows.view(3, batch, *rows.shape[1:])
    if isinstance(layer, nn.ReLU):  # relu(x) = x * [x > 0], and its tangent is t * [x > 0]
        return split.mul_(split[0] > 0).view(rows.shape)  # a multiply: 1.6x faster than masked_fill_
    if isinstance(layer, nn.Sigmoid):
        output = torch.sigmoid_(split[0])
        split[1:] *= output * (1 - output)
        return rows
    raise TypeError(f"no tangent rule for {type(layer).__name__}")


def _without_bias(layer, rows: torch.Tensor) -> torch.Tensor:
    if isinstance(layer, nn.Linear):
        if len(rows) <= 64:  # few rows: W x^T streams the weight once (measured 2x faster for 3 rows x 1024 x 8192)
            return (layer.weight @ rows.T).T.contiguous()
        return F.linear(rows, layer.weight)
    if isinstance(layer, nn.ConvTranspose2d):
        return F.conv_transpose2d(rows, layer.weight, None, layer.stride, layer.padding, layer.output_padding,
                                  layer.groups, layer.dilation)
    if isinstance(layer, nn.Conv2d):
        return F.conv2d(rows, layer.weight, None, layer.stride, layer.padding, layer.dilation, layer.groups)
    return layer.linear(rows)


class SubPixelTransposedConv(nn.Module):
    """ConvTranspose2d(kernel 4, stride 2, padding 1) as a 3x3 Conv2d to 4 x C_out channels and a pixel shuffle.

    Output pixel (2m + a, 2n + b) meets input rows m - 1 + a .. m + a and columns n - 1 + b .. n + b
    only: each of the four phases (a, b) is a 3x3 convolution with zeros at the taps it does not
    use. 2.25x the multiply-adds, but with one output channel oneDNN runs it 1.7x faster than the
    transposed convolution (measured 30 -> 18 ms at 24 x 16 x 128 x 128). The same function to
    float rounding.
    """

    TAPS = ({0: 1, -1: 3}, {1: 0, 0: 2})  # phase a -> {input offset i - m: kernel row of the transposed conv}

    def __init__(self, layer: nn.ConvTranspose2d):
        super().__init__()
        inputs, outputs = layer.weight.shape[:2]
        weight = torch.zeros(outputs, 4, inputs, 3, 3)  # (output channel, phase 2a + b): pixel_shuffle's order
        for a in (0, 1):
            for b in (0, 1):
                for row, tap_row in self.TAPS[a].items():
                    for column, tap_column in self.TAPS[b].items():
                        weight[:, 2 * a + b, :, row + 1, column + 1] = layer.weight.detach()[:, :, tap_row, tap_column].T
        self.weight = nn.Parameter(weight.view(4 * outputs, inputs, 3, 3), requires_grad=False)
        self.bias = None if layer.bias is None else nn.Parameter(layer.bias.detach().clone(), requires_grad=False)

    @staticmethod
    def applies_to(layer: nn.Module) -> bool:
        """A transposed convolution of this shape with one output channel (where it is faster)."""
        return (isinstance(layer, nn.ConvTranspose2d) and layer.kernel_size == (4, 4) and layer.stride == (2, 2)
                and layer.padding == (1, 1) and layer.output_padding == (0, 0) and layer.dilation == (1, 1)
                and layer.groups == 1 and layer.out_channels == 1)

    def linear(self, x: torch.Tensor) -> torch.Tensor:
        return F.pixel_shuffle(F.conv2d(x, self.weight, None, 1, 1), 2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.linear(x)
        return out if self.bias is None else out + self.bias.view(-1, 1, 1)


def optimised(model: GenerativeModel) -> TangentModel:
    """A copy of ``model`` with layer-by-layer JVPs and its convolutions in channels-last layout.

    The same function (to float rounding). On CPU, channels-last runs ConvTranspose2d and its
    tangent through oneDNN instead of a generic path (1.3-3x faster at 64x64 and 256x256), the
    written-out JVP halves the work of the Jacobian (2x faster), and the last, one-channel
    transposed convolution runs as a :class:`SubPixelTransposedConv`.
    """
    decoder = copy.deepcopy(model.decoder)
    if isinstance(decoder, ConvDecoder):
        for index, layer in enumerate(decoder.convolutions):
            if SubPixelTransposedConv.applies_to(layer):
                decoder.convolutions[index] = SubPixelTransposedConv(layer)
    decoder = decoder.to(memory_format=torch.channels_last)
    return TangentModel(decoder, model.rest_pose, model.half_ranges, model.metadata)


def linearised_terms(projected, squared, gram, step):
    """J^T e (B, 2) and e^T e (B,) of eqs. 4 and 6 (before the precision) for g(mu) ~ g0 + J0 d, J ~ J0.

    With e = s_v - g0 - J0 d and d = mu - mu0 (B, 2), from projected = J0^T (s_v - g0) (B, 2),
    squared = |s_v - g0|^2 (B,) and gram = J0^T J0 (B, 2, 2), all float64:
    J0^T e = projected - gram d and |e|^2 = squared - 2 d . projected + d^T gram d (>= 0 but for rounding).
    """
    drive = projected - (gram @ step[:, :, None])[:, :, 0]
    error = squared - 2 * (projected * step).sum(1) + (step[:, None] @ gram @ step[:, :, None]).view(-1)
    return drive, error.clamp(min=0)


class LinearisedDecoder(Decoder):
    """Decoder component with the tangent-linear fast mode; same variables plus relinearise_tolerance.

    checkpoint, name, resolution, rest_pose, half_ranges, threads: as for Decoder.
    relinearise_tolerance: start value of the parameter (deg, >= 0).
    fast_layout: run the decoder through :func:`optimised` (written-out JVPs, channels-last).
    memory_mb: room for stored linearisations (12 bytes a pixel each); at least 2 per trial.

    After a run: ``relinearisations`` (B,) counts how often each trial's linearisation point
    changed (the first included); ``call_sizes`` lists the points of each batched decoder call.
    """

    def __init__(self, checkpoint, name: str = "decoder", relinearise_tolerance: float = DEFAULT_TOLERANCE,
                 resolution: int | None = None, rest_pose=None, half_ranges=None, threads: int | None = None,
                 fast_layout: bool = True, memory_mb: float = 256.0):
        super().__init__(checkpoint, name, resolution, rest_pose, half_ranges, threads)
        if fast_layout:
            self.model = optimised(self.model)
        tolerance = Variable("relinearise_tolerance", "parameter", start=relinearise_tolerance, unit="deg", min=0.0,
                             description="take a new linearisation point when a joint of mu moves more than this from mu0")
        self.variables[tolerance.name] = tolerance
        self.memory_mb = memory_mb
        self.relinearisations = np.zeros(0, dtype=np.int64)
        self.call_sizes: list[int] = []

    @property
    def decoder_points(self) -> int:
        """Linearisation points the decoder evaluated."""
        return sum(self.call_sizes)

    @property
    def decoder_calls(self) -> int:
        return len(self.call_sizes)

    def initialize(self):
        torch.set_num_threads(self.threads)
        pixels = self.model.resolution ** 2
        capacity = max(2 * self.batch_size, int(self.memory_mb * 2**20) // (12 * pixels))
        self._store = torch.empty(capacity, 3, pixels)  # per point: g0, then J0's columns (shoulder, elbow)
        self._gram = torch.empty(capacity, 2, 2, dtype=torch.float64)  # J0^T J0
        self._points = np.full((capacity, 2), np.nan)    # deg; NaN: an empty slot
        self._last_used = np.full(capacity, -1)          # step count, for least-recently-used eviction
        self._slots = np.full(self.batch_size, -1)       # each trial's point; -1: none yet
        self._residual = torch.empty(self.batch_size, pixels)  # s - g0 of the trials at one point
        self._steps = 0
        self.relinearisations = np.zeros(self.batch_size, dtype=np.int64)
        self.call_sizes = []
        self._update()

    def stale(self, mu: np.ndarray) -> np.ndarray:
        """Trials (B,) bool that have no point yet or whose belief moved more than the tolerance from it."""
        moved = np.abs(mu - self._points[self._slots]).max(axis=1)
        return (self._slots < 0) | ~(moved <= self.values["relinearise_tolerance"])

    def reassign(self, trials: np.ndarray, mu: np.ndarray) -> None:
        """A new point for each of ``trials``: the nearest stored (or just chosen) point within its tolerance of its
        mu, else its mu itself; the new points are evaluated in one decoder call."""
        tolerance = self.values["relinearise_tolerance"]
        stored = np.flatnonzero(~np.isnan(self._points[:, 0]))
        candidates, owners = list(self._points[stored]), list(stored)  # owner -1 - k: the k-th new point
        new = []
        for trial in trials:
            distance = np.abs(np.array(candidates) - mu[trial]).max(axis=1) if candidates else np.array([np.inf])
            nearest = int(distance.argmin())
            if distance[nearest] <= tolerance[trial]:
                self._slots[trial] = owners[nearest]
            else:
                self._slots[trial] = -1 - len(new)
                candidates.append(mu[trial])
                owners.append(-1 - len(new))
                new.append(mu[trial])
        if new:
            keep = self._slots[self._slots >= 0]
            slots = self.linearise(np.array(new), keep)
            pending = self._slots < 0
            self._slots[pending] = slots[-1 - self._slots[pending]]
        self.relinearisations[trials] += 1

    def linearise(self, points: np.ndarray, keep: np.ndarray) -> np.ndarray:
        """g0, J0 and J0^T J0 at ``points`` (N, 2) in one decoder call, into slots other than ``keep``."""
        free = np.flatnonzero(np.isnan(self._points[:, 0]))
        if len(free) < len(points):  # evict the least recently used points that no trial stands on now
            spare = np.setdiff1d(np.flatnonzero(~np.isnan(self._points[:, 0])), keep)
            free = np.concatenate([free, spare[np.argsort(self._last_used[spare], kind="stable")]])
        slots = free[:len(points)]
        with torch.no_grad():
            prediction, jacobian = self.model.predict_with_jacobian(torch.from_numpy(points.astype(np.float32)))
        index = torch.from_numpy(slots)
        self._store[index, 0] = prediction.reshape(len(points), -1)
        self._store[index, 1:] = jacobian.reshape(len(points), 2, -1)
        self._gram[index] = jacobian_gram(jacobian).double()
        self._points[slots] = points
        self.call_sizes.append(len(points))
        return slots

    def _update(self):
        mu, image, precision = self._checked_inputs()
        batch, side = image.shape[0], image.shape[1]
        self._steps += 1
        stale = np.flatnonzero(self.stale(mu))
        if len(stale):
            self.reassign(stale, mu)
        slots = self._slots
        self._last_used[slots] = self._steps

        sensed = torch.from_numpy(image).view(batch, -1)
        projected, squared = torch.empty(batch, 2), torch.empty(batch)  # J0^T (s - g0), |s - g0|^2
        with torch.no_grad():
            for slot in np.unique(slots):  # one pass over each point in use and over each image
                trials = np.flatnonzero(slots == slot)
                residual = self._residual[:len(trials)]  # preallocated: a fresh 16 MB a step costs page faults
                if trials[-1] - trials[0] == len(trials) - 1:  # a run of trials: no gather
                    torch.sub(sensed[trials[0]:trials[-1] + 1], self._store[slot, 0], out=residual)
                else:
                    torch.index_select(sensed, 0, torch.from_numpy(trials), out=residual).sub_(self._store[slot, 0])
                projected[trials] = F.linear(residual, self._store[slot, 1:])
                squared[trials] = torch.linalg.vector_norm(residual, dim=1).square()
        step = mu - self._points[slots]  # d, float64
        gram = self._gram[torch.from_numpy(slots)]
        drive, error = linearised_terms(projected.double(), squared.double(), gram, torch.from_numpy(step))
        weight = precision.double()
        self.values["visual_drive"] = (drive * weight[:, None]).numpy()
        self.values["visual_error"] = (error * weight).numpy()
        self.values["visual_stiffness"] = largest_eigenvalue(gram * weight[:, None, None]).numpy()
        self.values["prediction"] = Deferred(self._prediction_of(slots, step, side))

    def _prediction_of(self, slots: np.ndarray, step: np.ndarray, side: int):
        """g0 + J0 d per trial (B, side, side) float32, for the points and steps of this step."""
        store, slots, step = self._store, torch.from_numpy(slots), torch.from_numpy(step.astype(np.float32))

        def compute():  # the store is unchanged until the next step, which replaces this output
            rows = store[slots]
            # A trial on its point exactly (d = 0) predicts g0 to the bit.
            return torch.baddbmm(rows[:, :1], step[:, None], rows[:, 1:]).view(-1, side, side).numpy()
        return compute
