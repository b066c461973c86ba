"""Presets, seeding and the small input helpers."""

from __future__ import annotations

import pytest
import torch

from tvf.errors import TvfError
from tvf.models.gctn import GCTN
from tvf.models.images import as_pixels, clamp_rgbh, from_rgbh, to_rgbh
from tvf.models.presets import PRESETS, SMOKE, ModelPreset, get_preset


def test_every_preset_keeps_images_and_rotations() -> None:
    for preset in PRESETS.values():
        assert preset.image_size == 160 and preset.n_rotations == 36
        assert ModelPreset.from_dict(preset.as_dict()) == preset


def test_bad_presets_raise_tvf_errors() -> None:
    with pytest.raises(TvfError, match="choose one of"):
        get_preset("huge")
    with pytest.raises(TvfError, match="multiples of 8"):
        SMOKE.replace(crop=30)
    with pytest.raises(TvfError, match="divisor of n_rotations"):
        SMOKE.replace(symmetry=5)
    with pytest.raises(TvfError, match="unknown preset fields"):
        ModelPreset.from_dict({**SMOKE.as_dict(), "depth": 3})


def test_seed_fixes_the_weights() -> None:
    a, b, c = GCTN(SMOKE, seed=3), GCTN(SMOKE, seed=3), GCTN(SMOKE, seed=4)
    for x, y in zip(a.parameters(), b.parameters(), strict=True):
        assert torch.equal(x, y)
    assert not all(torch.equal(x, z) for x, z in zip(a.parameters(), c.parameters(), strict=True))


def test_rgbh_round_trip_and_clamp(generator: torch.Generator) -> None:
    color = torch.randint(0, 256, (2, 160, 160, 3), generator=generator, dtype=torch.uint8)
    height = torch.rand(2, 160, 160, generator=generator) * 0.1
    rgbh = to_rgbh(color, height)
    assert rgbh.shape == (2, 4, 160, 160) and rgbh.dtype == torch.float32
    back_color, back_height = from_rgbh(rgbh)
    torch.testing.assert_close(back_color, color.float(), atol=1e-3, rtol=0)
    torch.testing.assert_close(back_height, height, atol=1e-6, rtol=0)
    clamped_color, clamped_height = from_rgbh(clamp_rgbh(rgbh * 100))
    assert clamped_color.min() >= -1e-3 and clamped_color.max() <= 255 + 1e-3
    assert clamped_height.min() >= -1e-6 and clamped_height.max() <= 0.28 + 1e-6


def test_pixels_must_be_integers() -> None:
    assert as_pixels([3, 4], 2).tolist() == [[3, 4], [3, 4]]
    with pytest.raises(ValueError, match="world_to_pixel"):
        as_pixels(torch.tensor([[3.0, 4.0]]), 1)
    with pytest.raises(ValueError, match="outside"):
        as_pixels(torch.tensor([[3, 4], [-1, 5]]), 2, (160, 160))
    with pytest.raises(ValueError, match="outside"):
        as_pixels(torch.tensor([[160, 4]]), 1, (160, 160))
