"""The latent-dynamics baseline: shapes, action input, loss, gradients, learning, inference, checkpoints."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from model_scenes import draw_blocks

from tvf.models.checkpoint import CheckpointError, load_checkpoint, load_model, save_checkpoint, save_weights
from tvf.models.images import clamp_rgbh, from_rgbh, to_rgbh
from tvf.models.latent import ACTION_FEATURES, LatentDynamics, encode_latent_action, rgbh_mse
from tvf.models.presets import LATENT_PRESETS, SMOKE, LatentPreset, PresetError, get_latent_preset
from tvf.models.vf import VisualForesight, vf_loss

SMALL = SMOKE.replace(image_size=64)
"""Smoke widths on 64 x 64 images (a 4 x 4 latent grid): the same network, 6x cheaper to train."""
MAX_STEPS = 250


def _inputs(b: int, generator: torch.Generator, size: int = 160):
    rgbh = torch.randn(b, 4, size, size, generator=generator)
    picks = torch.randint(0, size, (b, 2), generator=generator)
    places = torch.randint(0, size, (b, 2), generator=generator)
    return rgbh, picks, places, torch.rand(b, generator=generator) * 6.28


def test_the_action_is_a_vector_tiled_over_the_grid_with_each_cells_position() -> None:
    pick, place = torch.tensor([[0, 159], [80, 40]]), torch.tensor([[159, 0], [10, 150]])
    a = encode_latent_action(pick, place, torch.tensor([0.0, math.pi / 2]), 10, 160)
    assert a.shape == (2, ACTION_FEATURES, 10, 10)
    torch.testing.assert_close(a[0, :6, 3, 7], torch.tensor([-1.0, 1.0, 1.0, -1.0, 1.0, 0.0]))
    torch.testing.assert_close(a[1, :4, 0, 0], torch.tensor([80, 40, 10, 150]) * (2 / 159) - 1)
    torch.testing.assert_close(a[1, 4:6, 9, 2], torch.tensor([0.0, 1.0]), atol=1e-6, rtol=0)
    assert torch.equal(a[0, :6], a[0, :6, :1, :1].expand(6, 10, 10))  # the same vector in every cell
    centre = lambda i: (16 * i + 7.5) * (2 / 159) - 1  # noqa: E731  (cell i covers pixels 16i .. 16i+15)
    torch.testing.assert_close(a[1, 6, :, 4], torch.tensor([centre(i) for i in range(10)]))  # row
    torch.testing.assert_close(a[1, 7, 4, :], torch.tensor([centre(i) for i in range(10)]))  # col
    assert torch.equal(a[0, 6:], a[1, 6:])


def test_shapes_and_the_transition_starts_as_the_identity(generator: torch.Generator) -> None:
    model = LatentDynamics(SMOKE)
    rgbh, picks, places, yaws = _inputs(2, generator)
    z = model.encode(rgbh)
    assert z.shape == (2, LATENT_PRESETS["smoke"].channels, 10, 10)
    out = model(rgbh, picks, places, yaws)
    assert out.shape == (2, 4, 160, 160) and out.dtype == torch.float32
    # the transition's last layer starts at zero: the first prediction is the reconstruction
    torch.testing.assert_close(out, model.decode(z))


def test_the_loss_is_the_vfs_l1_of_the_next_image_plus_the_weighted_auxiliary_terms(generator) -> None:
    model = LatentDynamics(SMOKE, latent=LatentPreset(0.5, 8, recon_weight=0.25, latent_weight=0.5))
    rgbh, picks, places, yaws = _inputs(2, generator)
    target = torch.randn(2, 4, 160, 160, generator=generator)
    parts = model.losses(rgbh, picks, places, yaws, target)
    with torch.no_grad():
        torch.testing.assert_close(parts["next"], vf_loss(model(rgbh, picks, places, yaws), target))
        z = model.encode(rgbh)
        torch.testing.assert_close(parts["recon"], rgbh_mse(model.decode(z), rgbh))
        z_next = model.step(z, picks, places, yaws)
        torch.testing.assert_close(parts["latent"], (z_next - model.encode(target)).pow(2).mean())
    torch.testing.assert_close(parts["total"], parts["next"] + 0.25 * parts["recon"] + 0.5 * parts["latent"])
    assert rgbh_mse(torch.ones(1, 4, 2, 2), torch.zeros(1, 4, 2, 2)).item() == pytest.approx(2.0)
    weights = torch.full((2, 160, 160), 3.0)
    weighted = model.losses(rgbh, picks, places, yaws, target, weights)
    torch.testing.assert_close(weighted["next"], 3 * parts["next"])  # the weights are the next image's
    torch.testing.assert_close(weighted["recon"], parts["recon"])
    torch.testing.assert_close(weighted["latent"], parts["latent"])
    # the target's encoding is held fixed: the gradient is that of z' = step(encode(rgbh)) alone
    first = model.encoder.net[0].weight
    (grad,) = torch.autograd.grad(parts["latent"], first)
    with torch.no_grad():
        z_true = model.encode(target)
    manual = (model.step(model.encode(rgbh), picks, places, yaws) - z_true).pow(2).mean()
    torch.testing.assert_close(grad, torch.autograd.grad(manual, first)[0])
    plain = LatentDynamics(SMOKE, latent=LatentPreset(0.5, 8, recon_weight=0.0, latent_weight=0.0))
    only_next = plain.losses(rgbh, picks, places, yaws, target)
    assert only_next["recon"].item() == 0.0 and only_next["latent"].item() == 0.0
    assert torch.equal(only_next["total"], only_next["next"])


def test_gradients_reach_the_encoder_the_transition_and_the_decoder(generator: torch.Generator) -> None:
    model = LatentDynamics(SMOKE)
    rgbh, picks, places, yaws = _inputs(2, generator)
    target = torch.randn(2, 4, 160, 160, generator=generator)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    for step in range(2):  # the transition's zero last layer passes no gradient inward before step 1
        optimizer.zero_grad()
        model.loss(rgbh, picks, places, yaws, target).backward()
        if step == 0:
            assert model.transition.out.weight.grad.abs().sum() > 0
        optimizer.step()
    for name, p in model.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


def test_one_transition_is_learned_well_below_the_copy_baseline() -> None:
    blocks, target = [(14, 14), (40, 20), (22, 46)], (48, 48)
    current = to_rgbh(*draw_blocks(blocks, 64))
    after = to_rgbh(*draw_blocks([target, *blocks[1:]], 64))
    pick, place, yaw = torch.tensor([blocks[0]]), torch.tensor([target]), torch.zeros(1)
    copy = vf_loss(current, after).item()  # copying misses the block at the pick and at the place
    model = LatentDynamics(SMALL)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    first = model.losses(current, pick, place, yaw, after)["next"].item()
    for _ in range(MAX_STEPS):  # about 150 steps (5 s of one core); stop once the block has moved
        optimizer.zero_grad()
        parts = model.losses(current, pick, place, yaw, after)
        if parts["next"].item() < 0.4 * copy:
            break
        parts["total"].backward()
        optimizer.step()
    with torch.no_grad():
        pred = model(current, pick, place, yaw)
    assert vf_loss(pred, after).item() < 0.5 * copy < first
    _, height = from_rgbh(pred)
    half = 4  # the block's middle (13 x 13 blocks): moved away from the pick, arrived at the place
    assert height[0, target[0] - half : target[0] + half, target[1] - half : target[1] + half].mean() > 0.03
    assert height[0, 14 - half : 14 + half, 14 - half : 14 + half].mean() < 0.01


def test_prediction_is_chunked_clamped_and_physical(generator: torch.Generator) -> None:
    model = LatentDynamics(SMOKE).eval()
    b = 6  # more than the inference chunk
    rgbh, picks, places, yaws = _inputs(b, generator)
    with torch.no_grad():
        whole = clamp_rgbh(model(rgbh, picks, places, yaws))
    torch.testing.assert_close(model.predict_rgbh(rgbh, picks, places, yaws), whole)
    color, height = draw_blocks([(40, 40), (100, 90)])
    colors, heights = color.expand(2, -1, -1, -1).to(torch.uint8), height.expand(2, -1, -1)
    with torch.no_grad():
        model.decoder.out.bias.copy_(torch.tensor([1e3, -1e3, 1e3, -1e3]))  # every output out of range
    out_color, out_height = model.predict(colors, heights, np.array([[40, 40]] * 2), np.array([[9, 9]] * 2),
                                          np.zeros(2))  # fmt: skip
    assert out_color.shape == (2, 160, 160, 3) and out_height.shape == (2, 160, 160)
    assert torch.all(out_color[..., 0] == 255) and torch.all(out_color[..., 1] == 0)
    assert torch.all(out_height == 0)


def test_checkpoints_and_weights_round_trip_with_the_latent_sizes(tmp_path, generator) -> None:
    sizes = LatentPreset(width=0.25, channels=5, recon_weight=0.5, latent_weight=2.0)  # not the preset's
    model = LatentDynamics(SMOKE, seed=3, latent=sizes).eval()
    rgbh, picks, places, yaws = _inputs(2, generator)
    expected = model.predict_rgbh(rgbh, picks, places, yaws)
    for path in (save_checkpoint(tmp_path / "latent.pt", model, step=7),
                 save_weights(tmp_path / "latent.safetensors", model, step=7)):  # fmt: skip
        loaded, ckpt = load_model(path, "latent")
        assert isinstance(loaded, LatentDynamics) and ckpt.step == 7 and loaded.latent == sizes
        assert ckpt.config == {"preset": SMOKE.as_dict(), "latent": sizes.as_dict()}
        torch.testing.assert_close(loaded.eval().predict_rgbh(rgbh, picks, places, yaws), expected)
    other = LatentDynamics(SMOKE)  # the smoke sizes: a resume into it is refused, the sizes named
    with pytest.raises(CheckpointError, match="another config.*latent.channels"):
        load_checkpoint(tmp_path / "latent.pt", "latent", model=other)


def test_a_checkpoint_of_another_kind_is_one_clear_error(tmp_path) -> None:
    latent = save_checkpoint(tmp_path / "latent.pt", LatentDynamics(SMOKE))
    vf = save_checkpoint(tmp_path / "vf.pt", VisualForesight(SMOKE))
    for path, wanted, held in ((latent, "vf", "latent"), (vf, "latent", "vf")):
        with pytest.raises(CheckpointError) as info:
            load_model(path, wanted)
        message = str(info.value)
        assert message.count("\n") == 0
        assert f"holds a {held!r} model, expected {wanted!r}; pass a {wanted} checkpoint" in message


def test_latent_presets_are_checked() -> None:
    assert get_latent_preset("lite") == LATENT_PRESETS["lite"]
    assert LatentPreset.from_dict(LATENT_PRESETS["paper"].as_dict()) == LATENT_PRESETS["paper"]
    with pytest.raises(PresetError, match="no latent-dynamics sizes for preset 'huge'"):
        get_latent_preset("huge")
    with pytest.raises(PresetError, match="unknown latent preset fields"):
        LatentPreset.from_dict({"width": 1.0, "channels": 4, "depth": 3})
    for bad in ({"width": 0.0, "channels": 4}, {"width": 1.0, "channels": 0},
                {"width": 1.0, "channels": 4, "recon_weight": -1.0},
                {"width": 1.0, "channels": 4, "latent_weight": float("nan")}):  # fmt: skip
        with pytest.raises(PresetError):
            LatentPreset(**bad)
    with pytest.raises(PresetError, match="divisible by 16"):
        LatentDynamics(SMOKE.replace(image_size=168, vf_pad=0))
