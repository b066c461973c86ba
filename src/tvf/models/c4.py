"""Convolutions whose kernels are tied over quarter turns: exact C4 equivariance by construction.

A C4 network's feature maps are *regular fields*: each field is 4 channels, one per quarter turn
(channel ``4 * field + r``). Turning the input by 90 degrees (``torch.rot90``, k = 1) turns every
feature map the same way and moves each field's channels one place on (``r`` -> ``r + 1 mod 4``).
A layer keeps that property when its kernel for output turn ``r`` is the turn-0 kernel turned ``r``
times, with its input fields' channels shifted by ``r`` (the group convolution of Cohen & Welling
2016, the C4 network of Huang et al.'s Equivariant Transporter). The first layer *lifts* plain
image channels to fields; :func:`group_pool` averages each field's four channels back to one
turn-invariant channel, whose map then turns with the input.

Only a quarter of the kernel entries are free, but once assembled the kernel is an ordinary
``conv2d`` weight: a C4 layer costs what a plain layer with the same channels costs (assembled
once per call, cached while the weights do not change and no gradient is needed).

Downsampling is a 2 x 2 average (a 2 x 2 block of an even-sided map is a block again after a
quarter turn; taking every second pixel is not), so the C4 FCNs need even sides at every level.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

TURNS = 4
"""Channels of one regular field: the quarter turns."""


def check_fields(channels: int, what: str) -> int:
    """``channels // 4``; a channel count that is not whole fields is an error naming ``what``."""
    if channels % TURNS or channels <= 0:
        raise ValueError(f"{what} of a C4 layer must be a positive multiple of {TURNS}, got {channels}")
    return channels // TURNS


class C4Conv(nn.Module):
    """Square convolution with quarter-turn-tied kernels, bias per field; stride 2 averages 2 x 2 first.

    ``lifting``: the input is plain channels (an image) rather than fields. ``c_out`` (and ``c_in``
    unless lifting) count channels, four per field. Zero padding keeps the size (odd kernels).
    """

    def __init__(
        self,
        c_in: int,
        c_out: int,
        kernel: int,
        stride: int = 1,
        lifting: bool = False,
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        if kernel % 2 == 0:
            raise ValueError(f"a C4 layer needs an odd kernel (centred on a pixel), got {kernel}")
        if stride not in (1, 2):
            raise ValueError(f"a C4 layer's stride is 1 or 2, got {stride}")
        fields_out = check_fields(c_out, "output channels")
        if not lifting:
            check_fields(c_in, "input channels")
        self.in_channels, self.out_channels = c_in, c_out
        self.kernel, self.stride, self.lifting = kernel, stride, lifting
        # the turn-0 kernel of each output field; input channel 4 * field + r of a group layer
        self.weight = nn.Parameter(torch.empty(fields_out, c_in, kernel, kernel))
        self.bias = nn.Parameter(torch.zeros(fields_out))
        # Glorot-uniform with the assembled kernel's fans, as the plain layers are drawn.
        bound = math.sqrt(6.0 / ((c_in + c_out) * kernel * kernel))
        with torch.no_grad():
            self.weight.uniform_(-bound, bound, generator=generator)
        self._cache: tuple[tuple[int, int], torch.Tensor, torch.Tensor] | None = None

    def kernels(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The assembled ``conv2d`` weight (c_out, c_in, k, k) and bias (c_out)."""
        k, fields_out = self.kernel, self.out_channels // TURNS
        by_turn = self.weight.reshape(fields_out, -1, 1 if self.lifting else TURNS, k, k)
        turned = [torch.rot90(torch.roll(by_turn, shifts=r, dims=2), r, dims=(-2, -1)) for r in range(TURNS)]
        weight = torch.stack(turned, dim=1).reshape(self.out_channels, self.in_channels, k, k)
        return weight, self.bias.repeat_interleave(TURNS)

    def _assembled(self) -> tuple[torch.Tensor, torch.Tensor]:
        if self.training or torch.is_grad_enabled():
            self._cache = None
            return self.kernels()
        key = (self.weight._version, self.bias._version)
        if self._cache is None or self._cache[0] != key or self._cache[1].device != self.weight.device:
            weight, bias = self.kernels()
            self._cache = (key, weight, bias)
        return self._cache[1], self._cache[2]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.stride > 1:
            x = F.avg_pool2d(x, self.stride)
        weight, bias = self._assembled()
        return F.conv2d(x, weight, bias, padding=self.kernel // 2)

    def macs(self, output: torch.Tensor) -> int:
        """Multiply-accumulates of the assembled convolution for an output like ``output``."""
        return output.numel() * self.kernel * self.kernel * self.in_channels


def group_pool(fields: torch.Tensor) -> torch.Tensor:
    """(B, 4F, H, W) regular fields -> (B, F, H, W): each field's mean over its four turns."""
    b, c, h, w = fields.shape
    return fields.reshape(b, check_fields(c, "pooled channels"), TURNS, h, w).mean(dim=2)


def turn_fields(fields: torch.Tensor, k: int = 1) -> torch.Tensor:
    """What regular fields (B, 4F, H, W) become when the input turns ``k`` quarter turns."""
    b, c, h, w = fields.shape
    split = fields.reshape(b, check_fields(c, "turned channels"), TURNS, h, w)
    return torch.rot90(torch.roll(split, shifts=k, dims=2), k, dims=(-2, -1)).reshape(b, c, w, h)
