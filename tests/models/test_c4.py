"""Quarter-turn-tied kernels: every layer and the FCN are exactly equivariant, at the plain cost."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from tvf.models.backbone import count_conv_macs, count_parameters, resnet43_8s
from tvf.models.c4 import C4Conv, group_pool, turn_fields
from tvf.models.checkpoint import load_model, save_checkpoint
from tvf.models.gctn import GCTN
from tvf.models.presets import LITE, SMOKE, ModelPreset, PresetError
from tvf.models.symmetry import symmetrized, transform, transform_pixels, untransform


def _turn(x: torch.Tensor, k: int = 1) -> torch.Tensor:
    return torch.rot90(x, k, dims=(-2, -1))


@pytest.mark.parametrize(
    ("c_in", "kernel", "stride", "lifting"),
    [(3, 3, 1, True), (8, 3, 1, False), (8, 1, 2, False), (8, 1, 1, False)],
)
def test_each_layer_turns_its_fields_with_the_input(
    c_in: int, kernel: int, stride: int, lifting: bool, generator: torch.Generator
) -> None:
    conv = C4Conv(c_in, 12, kernel, stride, lifting=lifting, generator=generator)
    with torch.no_grad():
        conv.bias.uniform_(-1, 1, generator=generator)  # a bias per field, shared by its four turns
    x = torch.randn(2, c_in, 16, 16, generator=generator)
    moved = _turn(x) if lifting else turn_fields(x)
    for k in (1, 2, 3):
        moved_k = _turn(x, k) if lifting else turn_fields(x, k)
        torch.testing.assert_close(conv(moved_k), turn_fields(conv(x), k), rtol=1e-5, atol=1e-6)
    assert conv(moved).shape == (2, 12, 16 // stride, 16 // stride)


def test_untied_kernels_are_not_equivariant(generator: torch.Generator) -> None:
    """The check above can fail: a layer whose turn-1 kernel is not the turned turn-0 kernel breaks it."""
    conv = C4Conv(3, 8, 3, lifting=True, generator=generator)
    weight, bias = conv.kernels()
    weight = weight.clone()
    weight[1] += 0.1  # field 0, turn 1 no longer the turned turn-0 kernel
    x = torch.randn(1, 3, 16, 16, generator=generator)

    def untied(images: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.conv2d(images, weight, bias, padding=1)

    assert (untied(_turn(x)) - turn_fields(untied(x))).abs().max() > 1e-2


@pytest.mark.parametrize("width", [0.0625, 0.125])
def test_c4_fcn_is_exactly_equivariant_and_the_plain_one_is_not(width: float, generator) -> None:
    x = torch.randn(1, 8, 64, 64, generator=generator)
    c4 = resnet43_8s(8, 3, width, generator=generator, c4=True).eval()
    plain = resnet43_8s(8, 3, width, generator=generator).eval()
    with torch.no_grad():
        y = c4(x)
        assert y.shape == (1, 3, 64, 64)
        for k in (1, 2, 3):
            torch.testing.assert_close(c4(_turn(x, k)), _turn(y, k), rtol=1e-4, atol=1e-6)
        relative = (plain(_turn(x)) - _turn(plain(x))).norm() / plain(x).norm()
    assert relative > 0.05


def test_c4_costs_the_plain_convolutions_with_a_quarter_of_the_weights() -> None:
    plain = resnet43_8s(8, 1, LITE.attention_width)
    c4 = resnet43_8s(8, 1, LITE.attention_width, c4=True)
    shape = (1, 8, 160, 160)
    assert count_conv_macs(c4, shape) == pytest.approx(count_conv_macs(plain, shape), rel=0.01)
    assert count_parameters(c4) < 0.3 * count_parameters(plain)


def test_group_pool_averages_each_fields_turns() -> None:
    fields = torch.arange(16.0).reshape(1, 8, 1, 2)  # two fields of four channels, 1 x 2 pixels
    pooled = group_pool(fields)
    torch.testing.assert_close(pooled[0, :, 0, 0], torch.tensor([3.0, 11.0]))
    with pytest.raises(ValueError, match="multiple of 4"):
        group_pool(torch.zeros(1, 6, 2, 2))


def test_kernel_cache_follows_the_weights(generator: torch.Generator) -> None:
    conv = C4Conv(4, 8, 3, generator=generator).eval()
    x = torch.randn(1, 4, 8, 8, generator=generator)
    with torch.no_grad():
        first = conv(x)
        torch.testing.assert_close(conv(x), first)  # served from the cache
        conv.weight.mul_(2.0)
        torch.testing.assert_close(conv(x) - conv.bias.repeat_interleave(4)[:, None, None],
                                   2.0 * (first - conv.bias.repeat_interleave(4)[:, None, None]))  # fmt: skip
    conv.train()
    conv(x).sum().backward()  # with gradients the kernel is assembled again, so they reach the free weights
    assert conv.weight.grad is not None and conv.weight.grad.abs().sum() > 0


def test_c4_gctn_needs_no_symmetrising(generator: torch.Generator) -> None:
    """Its pick map equals its quarter-turn average exactly; its place maps up to the transport's crop,
    which is centred half a pixel off the pick (the plain GCTN is far off)."""
    current = torch.rand(1, 4, 160, 160, generator=generator)
    goal = torch.rand(1, 4, 160, 160, generator=generator)
    picks = torch.tensor([[[40, 70], [81, 100]]])
    gaps = {}
    for kernels in ("c4", "plain"):
        model = GCTN(LITE.replace(gctn_kernels=kernels)).eval()
        with torch.no_grad():
            pick = model.pick_logits(current, goal)
            place = model.place_maps(current, goal, picks)
            averaged = symmetrized(model, 4)
            gaps[kernels] = (
                float((averaged.pick_logits(current, goal) - pick).abs().max() / pick.abs().max()),
                float((averaged.place_maps(current, goal, picks) - place).norm() / place.norm()),
            )
            turn = (1, False)
            moved = torch.as_tensor(transform_pixels(picks.numpy(), turn, 160))
            turned_maps = model.place_maps(transform(current, turn), transform(goal, turn), moved)
            turned = untransform(turned_maps, turn)
            gaps[kernels] += (float((turned - place).norm() / place.norm()),)
    assert gaps["c4"][0] < 1e-4 and gaps["c4"][1] < 0.03 and gaps["c4"][2] < 0.03
    assert gaps["plain"][0] > 0.05 and gaps["plain"][2] > 0.1


def test_preset_field_keeps_old_stored_presets(tmp_path: Path) -> None:
    assert "gctn_kernels" not in LITE.as_dict()  # presets stored before the field stay byte-identical
    assert ModelPreset.from_dict(LITE.as_dict()) == LITE
    c4 = SMOKE.replace(gctn_kernels="c4")
    assert c4.as_dict()["gctn_kernels"] == "c4"
    with pytest.raises(PresetError, match="gctn_kernels must be one of plain, c4"):
        SMOKE.replace(gctn_kernels="c8")
    model = GCTN(c4, seed=3).eval()
    path = save_checkpoint(tmp_path / "c4.pt", model, step=1)
    rebuilt, _ = load_model(path, "gctn")
    assert rebuilt.preset == c4
    x = torch.rand(1, 4, 160, 160, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        torch.testing.assert_close(rebuilt.pick_logits(x, x), model.pick_logits(x, x))
