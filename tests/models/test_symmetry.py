"""Test-time C4 symmetrisation: exact equivariance of the averaged maps, identity at one turn."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tvf.errors import TvfError
from tvf.geometry import pixel_to_world, quarter_turn_pixels, rotate_xy
from tvf.models.gctn import GCTN
from tvf.models.presets import SMOKE
from tvf.models.symmetry import SymmetrizedGCTN, symmetrized

QUARTER = SMOKE.replace(symmetry=4, pad_features=True)


@pytest.mark.parametrize("turns", [1, 2, 3, 4, 5])
def test_quarter_turn_pixels_follow_rot90(turns: int) -> None:
    rng = np.random.default_rng(turns)
    pixels = rng.integers(0, 7, size=(5, 2))
    image = np.zeros((5, 7, 7))
    image[np.arange(5), pixels[:, 0], pixels[:, 1]] = 1
    turned = np.rot90(image, turns, axes=(1, 2))
    moved = quarter_turn_pixels(pixels, turns, 7)
    assert (turned[np.arange(5), moved[:, 0], moved[:, 1]] == 1).all()
    back = quarter_turn_pixels(moved, -turns, 7)
    assert (back == pixels).all()


def test_a_quarter_turn_is_a_world_yaw_of_minus_90_degrees() -> None:
    pixels = np.array([[0, 0], [10, 150], [159, 3]])
    centre = pixel_to_world(np.array([79.5, 79.5]))
    moved = pixel_to_world(quarter_turn_pixels(pixels, 1, 160)) - centre
    expected = rotate_xy(pixel_to_world(pixels) - centre, -np.pi / 2)
    np.testing.assert_allclose(moved, expected, atol=1e-12)


def _scene(generator: torch.Generator, b: int = 2):
    current = torch.randn(b, 4, 160, 160, generator=generator)
    goal = torch.randn(1, 4, 160, 160, generator=generator)
    picks = torch.randint(20, 140, (b, 2, 2), generator=generator)
    return current, goal, picks


@pytest.mark.parametrize("turns", [2, 4])
def test_symmetrised_maps_are_exactly_equivariant(generator: torch.Generator, turns: int) -> None:
    model = SymmetrizedGCTN(GCTN(QUARTER, seed=3).eval(), turns)
    current, goal, picks = _scene(generator)
    k = 4 // turns  # the smallest turn of the group
    turned_picks = torch.as_tensor(quarter_turn_pixels(picks.numpy(), k, 160))
    rot = lambda x: torch.rot90(x, k, dims=(-2, -1))  # noqa: E731
    with torch.no_grad():
        pick, pick_turned = model.pick_logits(current, goal), model.pick_logits(rot(current), rot(goal))
        place = model.place_maps(current, goal, picks)
        place_turned = model.place_maps(rot(current), rot(goal), turned_picks)
    torch.testing.assert_close(pick_turned, rot(pick), atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(place_turned, rot(place), atol=1e-5, rtol=1e-5)  # channels unchanged
    plain = GCTN(QUARTER, seed=3).eval()
    with torch.no_grad():
        alone, alone_turned = plain.pick_logits(current, goal), plain.pick_logits(rot(current), rot(goal))
    assert not torch.allclose(alone_turned, rot(alone), atol=1e-3)  # the network alone is not equivariant


def test_symmetrised_act_is_the_argmax_of_its_averaged_maps(generator: torch.Generator) -> None:
    plain = GCTN(QUARTER, seed=5).eval()
    model = symmetrized(plain, 4)
    current, goal, _ = _scene(generator)
    pick, place, rot, maps = model.act(current, goal)
    with torch.no_grad():
        expected = torch.stack([torch.rot90(plain.pick_logits(torch.rot90(current, k, (-2, -1)),
                                                              torch.rot90(goal, k, (-2, -1))), -k, (-2, -1))
                                for k in range(4)]).mean(0)  # fmt: skip
        cached = model.place_map(current, None, pick, goal_features=model.goal_features(goal))
    torch.testing.assert_close(maps["pick"], expected)
    torch.testing.assert_close(cached, maps["place"])
    flat = maps["pick"].reshape(2, -1).argmax(1)
    assert (pick[:, 0] * 160 + pick[:, 1] == flat).all()
    assert ((rot >= 0) & (rot < QUARTER.n_rotations)).all()


def test_the_symmetrised_loss_is_invariant_to_turns_and_trains_the_wrapped_gctn(generator) -> None:
    plain = GCTN(QUARTER, seed=7)
    model = SymmetrizedGCTN(plain, 4)
    current, goal, picks = _scene(generator)
    goal = goal.expand(2, -1, -1, -1)
    pick, place = picks[:, 0], picks[:, 1]
    bins = torch.tensor([3, 20])
    loss = model.loss(current, goal, pick, place, bins)
    turn = lambda x: torch.rot90(x, 1, dims=(-2, -1))  # noqa: E731
    moved = [torch.as_tensor(quarter_turn_pixels(p.numpy(), 1, 160)) for p in (pick, place)]
    turned = model.loss(turn(current), turn(goal), *moved, bins)  # the same sample, turned
    torch.testing.assert_close(turned["total"], loss["total"], atol=1e-4, rtol=1e-5)
    plain_loss = plain.loss(current, goal, pick, place, bins)
    assert not torch.isclose(plain_loss["total"], loss["total"])
    loss["total"].backward()
    grads = [p.grad for p in plain.parameters()]
    assert all(g is not None for g in grads) and any(g.abs().sum() > 0 for g in grads)


def test_one_turn_is_the_model_itself_and_bad_turns_are_refused() -> None:
    plain = GCTN(QUARTER)
    assert symmetrized(plain, 1) is plain
    with pytest.raises(TvfError, match="--turns must be 1, 2 or 4"):
        symmetrized(plain, 3)
    model = SymmetrizedGCTN(plain, 4)
    with pytest.raises(ValueError, match="expected goal features"):
        model.place_maps(torch.zeros(1, 4, 160, 160), None, torch.zeros(1, 1, 2, dtype=torch.int64),
                         plain.goal_features(torch.zeros(1, 4, 160, 160)))  # fmt: skip
