"""A faster copy of a decoder for CPUs: g(mu) and its Jacobian with the work halved and the kernels well used.

:func:`optimised` copies a :class:`GenerativeModel` into a :class:`TangentModel`, the same
function to float rounding (tested against torch.func.jvp). Each change below was kept because
it made the step faster on a CPU (docs/performance.md):

- forward-mode JVPs written out layer by layer, the primal and both tangents as one batch
  (half the FLOPs of two JVPs through PyTorch's own rules);
- channels-last layout (oneDNN kernels for ConvTranspose2d);
- a one-channel last ConvTranspose2d as a sub-pixel convolution (:class:`SubPixelTransposedConv`);
- dense layers with few rows as W x^T, and trials in chunks whose largest feature map fits the
  L3 cache (ACTIVATION_BUDGET).

Example::

    fast_model = optimised(model)
    prediction, jacobian = fast_model.predict_with_jacobian(mu_deg)   # (B, R, R), (B, 2, R, R)
"""
from __future__ import annotations

import copy

import torch
import torch.nn.functional as F
from torch import nn

from .component import GenerativeModel
from .networks import ConvDecoder, normalise

ACTIVATION_BUDGET = 24 * 2**20  # bytes of the largest feature map of one decoder pass: about this CPU's L3 (32 MB)


class TangentModel(GenerativeModel):
    """g(mu) and J by forward-mode AD written out layer by layer, for a ConvDecoder (others: as GenerativeModel).

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
        map stays within ACTIVATION_BUDGET: the layers then work in cache, at a higher FLOP rate than on
        the whole batch at once."""
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
        return split.mul_(split[0] > 0).view(rows.shape)  # a multiply: faster than masked_fill_
    if isinstance(layer, nn.Sigmoid):
        output = torch.sigmoid_(split[0])
        split[1:] *= output * (1 - output)
        return rows
    raise TypeError(f"no tangent rule for {type(layer).__name__}")


def _without_bias(layer, rows: torch.Tensor) -> torch.Tensor:
    if isinstance(layer, nn.Linear):
        if len(rows) <= 64:  # few rows: W x^T streams the weight once (faster than F.linear for a large W)
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
    use. 2.25x the multiply-adds, but with one output channel oneDNN runs it faster than the
    transposed convolution. The same function to float rounding.
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
        """The transposed convolution without its bias (its linear part, as the JVPs need it).

        Parameters
        ----------
        x : torch.Tensor
            (B, C_in, H, W).

        Returns
        -------
        torch.Tensor
            (B, C_out, 2H, 2W).
        """
        return F.pixel_shuffle(F.conv2d(x, self.weight, None, 1, 1), 2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """The transposed convolution of ``x`` (B, C_in, H, W), bias included: (B, C_out, 2H, 2W)."""
        out = self.linear(x)
        return out if self.bias is None else out + self.bias.view(-1, 1, 1)


def optimised(model: GenerativeModel) -> TangentModel:
    """A copy of ``model`` with layer-by-layer JVPs and its convolutions in channels-last layout.

    The same function (to float rounding). On CPU, channels-last runs ConvTranspose2d and its
    tangent through oneDNN instead of a generic path, the written-out JVP halves the work of the
    Jacobian, and the last, one-channel transposed convolution runs as a
    :class:`SubPixelTransposedConv`.
    """
    decoder = copy.deepcopy(model.decoder)
    if isinstance(decoder, ConvDecoder):
        for index, layer in enumerate(decoder.convolutions):
            if SubPixelTransposedConv.applies_to(layer):
                decoder.convolutions[index] = SubPixelTransposedConv(layer)
    decoder = decoder.to(memory_format=torch.channels_last)
    return TangentModel(decoder, model.rest_pose, model.half_ranges, model.metadata)
