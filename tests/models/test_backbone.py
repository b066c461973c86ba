"""ResNet43_8s / ResNet36_4s shapes, sizes and the channels-last path."""

from __future__ import annotations

import pytest
import torch
from torch.nn import functional as F

from tvf.models.backbone import (
    SubsampledPointwiseConv,
    count_conv_macs,
    count_parameters,
    resnet36_4s,
    resnet43_8s,
)


@pytest.mark.parametrize("size", [160, 224])
def test_resnet43_8s_keeps_size(size: int) -> None:
    net = resnet43_8s(8, 3, width=0.0625)
    out = net(torch.zeros(2, 8, size, size))
    assert out.shape == (2, 3, size, size)


@pytest.mark.parametrize("size", [160, 204])
def test_resnet36_4s_keeps_size(size: int) -> None:
    net = resnet36_4s(9, 4, width=0.0625)
    assert net(torch.zeros(1, 9, size, size)).shape == (1, 4, size, size)


def test_reference_sizes() -> None:
    """Full width matches the reference ResNet43_8s (6 -> 1 channels): 9.83 M params, 11.5 GMAC at 160^2."""
    net = resnet43_8s(6, 1, width=1.0)
    assert count_parameters(net) == 9_833_203
    assert count_conv_macs(net, (1, 6, 160, 160)) == pytest.approx(11.53e9, rel=1e-3)


def test_channels_last_matches_nchw(generator: torch.Generator) -> None:
    a = resnet43_8s(4, 3, width=0.0625, channels_last=True)
    b = resnet43_8s(4, 3, width=0.0625, channels_last=False)
    b.load_state_dict(a.state_dict())
    x = torch.randn(2, 4, 64, 64, generator=generator)
    torch.testing.assert_close(a(x), b(x), rtol=1e-4, atol=1e-5)


def test_subsampled_pointwise_equals_strided_conv(generator: torch.Generator) -> None:
    conv = SubsampledPointwiseConv(5, 7, stride=2)
    x = torch.randn(2, 5, 51, 50, generator=generator)
    expected = F.conv2d(x, conv.weight, conv.bias, stride=2)
    torch.testing.assert_close(conv(x), expected)
