"""Fully convolutional bottleneck ResNets used by the GCTN and the visual-foresight model.

Two layouts, both NCHW, with a width multiplier that scales every hidden channel count:

* :func:`resnet43_8s` -- the Transporter / GCTN FCN: a 3x3 stem, five bottleneck stages down to 1/8
  resolution (64, 128, 256, 512, 256 channels), then three bilinear x2 upsamplings with 128, 64 and
  (16, 16, out) stages. The last stage has no activation.
* :func:`resnet36_4s` -- the visual-foresight encoder-decoder: 64-channel stages down to 1/4
  resolution and back with bilinear upsampling, last stage (16, 16, out) without activation.

Every stage is a *conv block* (bottleneck 1x1 (stride) / 3x3 / 1x1 plus a 1x1 strided projection
shortcut) followed by an *identity block* (same bottleneck, identity shortcut). Convolutions have
biases and Glorot-uniform weights, and there is no normalisation layer, as in the reference.

With ``c4=True`` every convolution is a :class:`tvf.models.c4.C4Conv` (kernels tied over quarter
turns, 2 x 2 averages instead of strides) and the output is group-pooled: the FCN is then exactly
equivariant to quarter turns of its input, at the cost of the plain FCN with the same channels.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional as F

from tvf.models.c4 import TURNS, C4Conv, group_pool

MIN_CHANNELS = 4


def scaled(channels: int, width: float, c4: bool = False) -> int:
    """Hidden channel count ``channels * width``, rounded, never below :data:`MIN_CHANNELS`; with
    ``c4`` rounded to whole fields of four channels."""
    if c4:
        return TURNS * max(1, int(round(channels * width / TURNS)))
    return max(MIN_CHANNELS, int(round(channels * width)))


class SubsampledPointwiseConv(nn.Conv2d):
    """1x1 convolution with stride ``s``, computed as ``conv1x1(x[..., ::s, ::s])`` (same result).

    torch 2.13's oneDNN backward of a strided 1x1 conv on channels-last inputs with few (< 16)
    channels segfaults on this CPU; subsampling first avoids that kernel and is no slower.
    """

    def __init__(self, c_in: int, c_out: int, stride: int) -> None:
        super().__init__(c_in, c_out, 1, bias=True)
        self.subsample = stride

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.subsample > 1:
            x = x[:, :, :: self.subsample, :: self.subsample]
        return super().forward(x)


def _conv(
    c_in: int, c_out: int, kernel: int, stride: int = 1, generator: torch.Generator | None = None,
    c4: bool = False,
) -> nn.Module:  # fmt: skip
    """Conv with bias, Glorot-uniform weights drawn from ``generator``, zero bias (C4-tied if ``c4``)."""
    if c4:
        return C4Conv(c_in, c_out, kernel, stride, generator=generator)
    if kernel == 1:
        conv: nn.Conv2d = SubsampledPointwiseConv(c_in, c_out, stride)
    else:
        conv = nn.Conv2d(c_in, c_out, kernel, stride=stride, padding=kernel // 2, bias=True)
    nn.init.xavier_uniform_(conv.weight, generator=generator)
    nn.init.zeros_(conv.bias)
    return conv


class Bottleneck(nn.Module):
    """1x1 (stride) -> ReLU -> 3x3 -> ReLU -> 1x1, plus a shortcut, then ReLU unless ``activation=False``.

    The shortcut is a strided 1x1 projection when ``project`` (a "conv block"), else the identity.
    """

    def __init__(
        self,
        c_in: int,
        filters: tuple[int, int, int],
        stride: int,
        project: bool,
        activation: bool,
        generator: torch.Generator | None = None,
        c4: bool = False,
    ) -> None:
        super().__init__()
        f1, f2, f3 = filters
        if not project and (stride != 1 or c_in != f3):
            raise ValueError("an identity block needs stride 1 and equal input/output channels")
        self.reduce = _conv(c_in, f1, 1, stride, generator, c4)
        self.mix = _conv(f1, f2, 3, 1, generator, c4)
        self.expand = _conv(f2, f3, 1, 1, generator, c4)
        self.shortcut = _conv(c_in, f3, 1, stride, generator, c4) if project else nn.Identity()
        self.activation = activation

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # In-place ReLUs are safe here (convolutions and additions do not keep their outputs for
        # backward) and save a full-resolution tensor each.
        y = self.expand(F.relu(self.mix(F.relu(self.reduce(x), inplace=True)), inplace=True))
        y = y + self.shortcut(x)
        return F.relu(y, inplace=True) if self.activation else y


class Stage(nn.Sequential):
    """A conv block followed by an identity block."""

    def __init__(
        self,
        c_in: int,
        filters: tuple[int, int, int],
        stride: int,
        activation: bool,
        generator: torch.Generator | None = None,
        c4: bool = False,
    ) -> None:
        super().__init__(
            Bottleneck(c_in, filters, stride, True, activation, generator, c4),
            Bottleneck(filters[2], filters, 1, False, activation, generator, c4),
        )


class Upsample2x(nn.Module):
    """Bilinear x2 upsampling (``align_corners=False``, which matches Keras ``UpSampling2D``)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)


@dataclass(frozen=True)
class StageSpec:
    """One stage: bottleneck filters, stride, whether to upsample x2 first, final ReLU."""

    filters: tuple[int, int, int]
    stride: int = 1
    upsample: bool = False
    activation: bool = True


class BottleneckFCN(nn.Module):
    """3x3 stem conv + ReLU, then a list of :class:`Stage` s (optionally preceded by upsampling).

    The output keeps the input's spatial size when the strides and upsamplings balance. With
    ``channels_last`` the weights and every input use the channels-last memory format (faster on CPU).
    Weights are drawn from ``generator`` (the global RNG when None). With ``c4`` the stem lifts the
    image to regular fields, every layer is quarter-turn tied, and the last stage's fields are
    group-pooled: ``out_channels`` is a quarter of its channels.
    """

    def __init__(
        self,
        in_channels: int,
        stem: int,
        stages: list[StageSpec],
        channels_last: bool = True,
        generator: torch.Generator | None = None,
        c4: bool = False,
    ):
        super().__init__()
        self.in_channels = in_channels
        self.c4 = c4
        self.out_channels = stages[-1].filters[2] // (TURNS if c4 else 1)
        if c4:
            self.stem: nn.Module = C4Conv(in_channels, stem, 3, lifting=True, generator=generator)
        else:
            self.stem = _conv(in_channels, stem, 3, 1, generator)
        layers: list[nn.Module] = []
        c = stem
        for spec in stages:
            if spec.upsample:
                layers.append(Upsample2x())
            layers.append(Stage(c, spec.filters, spec.stride, spec.activation, generator, c4))
            c = spec.filters[2]
        self.body = nn.Sequential(*layers)
        self.downsampling = 1
        for spec in stages:
            self.downsampling *= spec.stride
        self.channels_last = channels_last
        if channels_last:
            self.to(memory_format=torch.channels_last)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.channels_last:
            x = x.contiguous(memory_format=torch.channels_last)
        y = self.body(F.relu(self.stem(x), inplace=True))
        return group_pool(y) if self.c4 else y


def resnet43_8s(
    in_channels: int,
    out_channels: int,
    width: float = 1.0,
    channels_last: bool = True,
    generator: torch.Generator | None = None,
    c4: bool = False,
) -> BottleneckFCN:
    """ResNet43_8s-like FCN (Transporter attention / transport nets). Input sides must divide by 8
    (then the 2 x 2 averages of ``c4`` see even sides at every level)."""

    def w(c: int) -> int:
        return scaled(c, width, c4)

    outputs = out_channels * (TURNS if c4 else 1)
    stages = [
        StageSpec((w(64), w(64), w(64)), 1),
        StageSpec((w(128), w(128), w(128)), 2),
        StageSpec((w(256), w(256), w(256)), 2),
        StageSpec((w(512), w(512), w(512)), 2),
        StageSpec((w(256), w(256), w(256)), 1),
        StageSpec((w(128), w(128), w(128)), 1, upsample=True),
        StageSpec((w(64), w(64), w(64)), 1, upsample=True),
        StageSpec((w(16), w(16), outputs), 1, upsample=True, activation=False),
    ]
    return BottleneckFCN(in_channels, w(64), stages, channels_last, generator, c4)


def resnet36_4s(
    in_channels: int,
    out_channels: int,
    width: float = 1.0,
    channels_last: bool = True,
    generator: torch.Generator | None = None,
) -> BottleneckFCN:
    """ResNet36_4s-like encoder-decoder (the VF "resnet_lite"). Input sides must divide by 4."""
    c = scaled(64, width)
    stages = [
        StageSpec((c, c, c), 1),
        StageSpec((c, c, c), 2),
        StageSpec((c, c, c), 2),
        StageSpec((c, c, c), 1, upsample=True),
        StageSpec((scaled(16, width), scaled(16, width), out_channels), 1, upsample=True, activation=False),
    ]
    return BottleneckFCN(in_channels, c, stages, channels_last, generator)


def count_parameters(module: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)


def count_conv_macs(module: nn.Module, input_shape: tuple[int, int, int, int]) -> int:
    """Multiply-accumulates of every Conv2d and :class:`C4Conv` for one forward pass at
    ``input_shape`` (N, C, H, W)."""
    total = 0

    def hook(conv: nn.Module, _inputs: tuple[torch.Tensor, ...], output: torch.Tensor) -> None:
        nonlocal total
        if isinstance(conv, C4Conv):
            total += conv.macs(output)
            return
        k = conv.kernel_size[0] * conv.kernel_size[1] * (conv.in_channels // conv.groups)
        total += output.numel() * k

    convs = (nn.Conv2d, C4Conv)
    handles = [m.register_forward_hook(hook) for m in module.modules() if isinstance(m, convs)]
    try:
        with torch.no_grad():
            module(torch.zeros(input_shape))
    finally:
        for h in handles:
            h.remove()
    return total


def set_channels_last(module: nn.Module, enabled: bool) -> nn.Module:
    """Switch every :class:`BottleneckFCN` inside ``module`` to (or from) the channels-last format.

    Weights are the same either way; only the memory layout (and the speed) changes.
    """
    fmt = torch.channels_last if enabled else torch.contiguous_format
    for sub in module.modules():
        if isinstance(sub, BottleneckFCN):
            sub.channels_last = enabled
            sub.to(memory_format=fmt)
    return module
