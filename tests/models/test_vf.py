"""Visual foresight: action encoding geometry, loss, overfitting, clamped physical predictions."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from model_scenes import BLOCK, draw_blocks, pick_place_batch

from tvf.geometry import rotate_pixels
from tvf.models.checkpoint import load_model, save_checkpoint
from tvf.models.images import clamp_rgbh, from_rgbh, to_rgbh
from tvf.models.presets import SMOKE, PresetError
from tvf.models.vf import CHANGED_MM, VisualForesight, changed_pixel_weights, encode_action, vf_loss

WINDOW = SMOKE.vf_window


def _block_with_mark(pick: np.ndarray, mark_offset: tuple[int, int]) -> tuple[torch.Tensor, np.ndarray]:
    """Normalised-looking RGB-H: a 13 x 13 block of ones at ``pick`` and a 3 x 3 mark of 5s inside it."""
    image = torch.zeros(1, 4, 160, 160)
    half = BLOCK // 2
    image[0, :, pick[0] - half : pick[0] + half + 1, pick[1] - half : pick[1] + half + 1] = 1.0
    mark = pick + np.array(mark_offset)
    image[0, :, mark[0] - 1 : mark[0] + 2, mark[1] - 1 : mark[1] + 2] = 5.0
    return image, mark.astype(float)


def _centroid(mask: torch.Tensor) -> np.ndarray:
    idx = torch.nonzero(mask).double()
    return idx.mean(0).numpy()


def test_pick_mask_is_the_44_window_around_the_pick() -> None:
    image = torch.zeros(2, 4, 160, 160)
    pick = torch.tensor([[80, 30], [5, 150]])
    x = encode_action(image, pick, pick, torch.zeros(2), WINDOW)
    assert x.shape == (2, 9, 160, 160)
    torch.testing.assert_close(x[0, 4], _window(80, 30))
    torch.testing.assert_close(x[1, 4], _window(5, 150))


def _window(row: int, col: int) -> torch.Tensor:
    w = torch.zeros(160, 160)
    w[max(row - WINDOW // 2, 0) : row + WINDOW // 2, max(col - WINDOW // 2, 0) : col + WINDOW // 2] = 1.0
    return w


@pytest.mark.parametrize("yaw_deg", [0.0, 90.0, 180.0, -90.0, 30.0, 135.0])
def test_place_mask_moves_the_block_and_turns_it_by_the_yaw(yaw_deg: float) -> None:
    pick, place = np.array([50, 40]), np.array([110, 120])
    image, mark = _block_with_mark(pick, (-4, 3))
    yaw = math.radians(yaw_deg)
    x = encode_action(
        image, torch.tensor(np.array([pick])), torch.tensor(np.array([place])), torch.tensor([yaw]), 44
    )
    placed = x[0, 8]
    block = placed > 0.5
    assert block.sum().item() == pytest.approx(BLOCK**2, rel=0.1)
    np.testing.assert_allclose(_centroid(block), place, atol=0.5)
    expected_mark = rotate_pixels(mark, yaw, pick) + (place - pick)
    np.testing.assert_allclose(_centroid(placed > 2.5), expected_mark, atol=1.0)
    assert (placed * (1 - _window(*place))).abs().sum() == 0  # nothing outside the place window


def test_loss_weights_height_five_times() -> None:
    target = torch.zeros(1, 4, 8, 8)
    colour_error = target.clone()
    colour_error[:, 0] = 1.0
    height_error = target.clone()
    height_error[:, 3] = 1.0
    assert vf_loss(colour_error, target).item() == pytest.approx(0.25)
    assert vf_loss(height_error, target).item() == pytest.approx(1.25)


@pytest.mark.parametrize("pad", [0, 22])
def test_output_is_the_unpadded_image(pad: int, generator: torch.Generator) -> None:
    model = VisualForesight(SMOKE.replace(vf_pad=pad))
    rgbh = torch.randn(2, 4, 160, 160, generator=generator)
    out = model(
        rgbh, torch.tensor([[10, 10], [100, 50]]), torch.tensor([[40, 40], [150, 150]]), torch.zeros(2)
    )
    assert out.shape == (2, 4, 160, 160)


def test_fixed_batch_overfits(generator: torch.Generator) -> None:
    model = VisualForesight(SMOKE)
    batch = pick_place_batch(2, generator)
    yaws = torch.zeros(2)
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(40):
        optimizer.zero_grad()
        loss = model.loss(batch["current"], batch["pick"], batch["place"], yaws, batch["goal"])
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[-1] < 0.4 * losses[0]


def test_chunked_prediction_equals_one_batch(generator: torch.Generator) -> None:
    model = VisualForesight(SMOKE)
    b = 11  # more than INFERENCE_CHUNK
    rgbh = torch.randn(b, 4, 160, 160, generator=generator)
    picks = torch.randint(0, 160, (b, 2), generator=generator)
    places = torch.randint(0, 160, (b, 2), generator=generator)
    yaws = torch.rand(b, generator=generator) * 6.28
    torch.testing.assert_close(
        model.predict_rgbh(rgbh, picks, places, yaws), clamp_rgbh(model(rgbh, picks, places, yaws).detach())
    )


def test_predict_is_batched_and_clamped() -> None:
    model = VisualForesight(SMOKE)
    color, height = draw_blocks([(40, 40), (100, 90)])
    colors, heights = color.expand(3, -1, -1, -1).to(torch.uint8), height.expand(3, -1, -1)
    picks = np.array([[40, 40], [100, 90], [40, 40]])
    places = np.array([[120, 120], [20, 30], [40, 41]])
    yaws = np.array([0.0, 1.0, -2.0])
    expected_color, expected_height = from_rgbh(
        model.predict_rgbh(to_rgbh(colors, heights), picks, places, yaws)
    )
    out_color, out_height = model.predict(colors, heights, picks, places, yaws)
    assert out_color.shape == (3, 160, 160, 3) and out_height.shape == (3, 160, 160)
    torch.testing.assert_close(out_height, expected_height.clamp(0, 0.28))
    for sign in (1.0, -1.0):
        with torch.no_grad():
            model.fcn.body[-1][-1].expand.bias.fill_(sign * 1e3)  # push every output far out of range
        out_color, out_height = model.predict(colors, heights, picks, places, yaws)
        bound_color, bound_height = (255.0, 0.28) if sign > 0 else (0.0, 0.0)
        assert torch.all(out_color == bound_color) and torch.allclose(out_height, torch.tensor(bound_height))
        assert (
            out_color.min() >= 0
            and out_color.max() <= 255
            and out_height.min() >= 0
            and out_height.max() <= 0.28
        )


def test_blend_head_keeps_untouched_pixels_and_round_trips(tmp_path):
    preset = SMOKE.replace(vf_head="blend")
    model = VisualForesight(preset, seed=0).eval()
    rgbh = torch.randn(2, 4, 160, 160, generator=torch.Generator().manual_seed(1))
    pick, place = torch.tensor([[40, 40], [100, 60]]), torch.tensor([[120, 120], [30, 130]])
    yaws = torch.tensor([0.3, -1.0])
    with torch.no_grad():
        for conv in [m for m in model.modules() if isinstance(m, torch.nn.Conv2d)][-1:]:
            conv.weight.zero_()
            conv.bias.zero_()
            conv.bias[4] = 30.0  # the keep logit wins everywhere
        out = model(rgbh, pick, place, yaws)
    assert out.shape == rgbh.shape
    torch.testing.assert_close(out, rgbh, atol=1e-6, rtol=0)
    with torch.no_grad():
        conv.bias[4], conv.bias[5] = 0.0, 30.0  # now the pasted window wins everywhere
        pasted = model(rgbh, pick, place, yaws)
    window = preset.vf_window // 2
    r, c = place[0].tolist()
    assert not torch.allclose(pasted[0, :, r - window : r + window, c - window : c + window],
                              rgbh[0, :, r - window : r + window, c - window : c + window])  # fmt: skip
    torch.testing.assert_close(pasted[0, :, :10, :10], rgbh[0, :, :10, :10])  # outside the window: kept
    path = save_checkpoint(tmp_path / "vf.pt", model)
    loaded, _ = load_model(path, "vf")
    assert loaded.preset.vf_head == "blend"
    with pytest.raises(PresetError, match="vf_head"):
        SMOKE.replace(vf_head="magic")


def test_changed_pixel_weights_single_out_moved_height() -> None:
    current = torch.zeros(2, 8, 8)
    after = current.clone()
    after[0, 2, 3] = CHANGED_MM / 1000 * 2  # a block arrived
    after[1, 5, 5] = CHANGED_MM / 1000 / 2  # below the threshold: noise, not a change
    weights = changed_pixel_weights(current, after, 9.0)
    assert weights[0, 2, 3] == 10.0 and weights.sum() == 2 * 64 + 9.0
    target = torch.zeros(2, 4, 8, 8)
    error = target.clone()
    error[0, 3, 2, 3] = 1.0  # a height error on the changed pixel only
    assert vf_loss(error, target, weights).item() == pytest.approx(10 * vf_loss(error, target).item())
    assert vf_loss(error, target, torch.ones(2, 8, 8)).item() == pytest.approx(vf_loss(error, target).item())


def test_local_head_redraws_only_the_pick_and_place_windows() -> None:
    preset = SMOKE.replace(vf_head="local")
    model = VisualForesight(preset, seed=0).eval()
    rgbh = torch.randn(2, 4, 160, 160, generator=torch.Generator().manual_seed(1))
    pick, place = torch.tensor([[40, 40], [100, 60]]), torch.tensor([[120, 120], [30, 130]])
    with torch.no_grad():
        out = model(rgbh, pick, place, torch.tensor([0.3, -1.0]))
        drawn = VisualForesight(SMOKE, seed=0).eval()(rgbh, pick, place, torch.tensor([0.3, -1.0]))
    half = preset.vf_window // 2
    inside = torch.zeros(2, 1, 160, 160, dtype=torch.bool)
    for b in range(2):
        for r, c in (pick[b].tolist(), place[b].tolist()):
            inside[b, :, r - half : r + half, c - half : c + half] = True
    inside = inside.expand_as(out)
    assert torch.equal(out[~inside], rgbh[~inside])  # every untouched pixel is the input's, exactly
    torch.testing.assert_close(out[inside], drawn[inside])  # inside: the same FCN's drawing
    assert not torch.allclose(out[inside], rgbh[inside])


def test_rollout_loss_feeds_the_clamped_prediction_back_and_backpropagates_through_it() -> None:
    torch.manual_seed(0)
    vf = VisualForesight(SMOKE, seed=3)
    g = torch.Generator().manual_seed(1)
    state = torch.randn(2, 4, 160, 160, generator=g)
    picks = torch.tensor([[[40, 50], [90, 100]], [[60, 70], [30, 120]]])
    places = torch.tensor([[[80, 80], [50, 40]], [[100, 30], [70, 70]]])
    yaws = torch.tensor([[0.3, -0.2], [0.0, 1.0]])
    targets = [torch.randn(2, 4, 160, 160, generator=g) for _ in range(2)]
    weights = [torch.rand(2, 160, 160, generator=g) + 1 for _ in range(2)]
    with torch.no_grad():
        first = vf(state, picks[:, 0], places[:, 0], yaws[:, 0])
        second = vf(clamp_rgbh(first), picks[:, 1], places[:, 1], yaws[:, 1])
        expected = (vf_loss(first, targets[0], weights[0]) + vf_loss(second, targets[1], weights[1])) / 2
        one_step = vf.loss(state, picks[:, 0], places[:, 0], yaws[:, 0], targets[0])
        assert torch.allclose(vf.rollout_loss(state, picks, places, yaws, targets, weights), expected)
        assert torch.allclose(vf.rollout_loss(state, picks[:, :1], places[:, :1], yaws[:, :1], targets[:1]),
                              one_step)  # fmt: skip
    # the second step's loss reaches the weights through the first prediction too
    second_only = [targets[0], targets[1]]
    loss = vf.rollout_loss(state, picks, places, yaws, second_only, [torch.zeros(2, 160, 160), weights[1]])
    loss.backward()
    through = {n: p.grad.clone() for n, p in vf.named_parameters()}
    vf.zero_grad()
    with torch.no_grad():
        fed = clamp_rgbh(vf(state, picks[:, 0], places[:, 0], yaws[:, 0]))
    (vf_loss(vf(fed, picks[:, 1], places[:, 1], yaws[:, 1]), targets[1], weights[1]) / 2).backward()
    detached = {n: p.grad.clone() for n, p in vf.named_parameters()}
    assert any(not torch.allclose(through[n], detached[n]) for n in through)
