"""Test-time C4 symmetrisation: exact equivariance of the averaged maps, identity at one turn."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tvf.errors import TvfError
from tvf.geometry import mirror_pixels, pixel_to_world, quarter_turn_pixels, rotate_xy
from tvf.models.gctn import GCTN
from tvf.models.presets import SMOKE
from tvf.models.symmetry import (
    SymmetrizedGCTN,
    group_elements,
    mirrored_channels,
    symmetrized,
    transform,
    transform_pixels,
    untransform,
)

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


def test_mirror_pixels_follow_flip_and_a_mirror_negates_world_yaws() -> None:
    rng = np.random.default_rng(0)
    pixels = rng.integers(0, 7, size=(5, 2))
    image = np.zeros((5, 7, 7))
    image[np.arange(5), pixels[:, 0], pixels[:, 1]] = 1
    moved = mirror_pixels(pixels, 7)
    assert (np.flip(image, axis=-1)[np.arange(5), moved[:, 0], moved[:, 1]] == 1).all()
    assert (mirror_pixels(moved, 7) == pixels).all()
    # in the world the mirror is a reflection M (det -1) about the image centre, and M R(t) = R(-t) M
    centre = pixel_to_world(np.array([79.5, 79.5]))
    points = rng.uniform(0, 159, size=(6, 2))
    world, world_mirrored = (
        pixel_to_world(points) - centre,
        pixel_to_world(mirror_pixels(points, 159 + 1)) - centre,
    )
    m = np.linalg.lstsq(world, world_mirrored, rcond=None)[0].T
    np.testing.assert_allclose(world @ m.T, world_mirrored, atol=1e-12)
    assert np.isclose(np.linalg.det(m), -1.0) and np.allclose(m @ m, np.eye(2))
    np.testing.assert_allclose(rotate_xy(world_mirrored, -0.3), rotate_xy(world, 0.3) @ m.T, atol=1e-12)


def test_the_eight_symmetries_are_a_group_of_exact_pixel_permutations(generator: torch.Generator) -> None:
    elements = group_elements(8)
    assert len(set(elements)) == 8 and elements[0] == (0, False)
    assert group_elements(4) == ((0, False), (1, False), (2, False), (3, False))
    image = torch.randn(2, 3, 6, 6, generator=generator)
    pixels = np.array([[0, 1], [4, 5], [2, 2]])
    for g in elements:
        torch.testing.assert_close(untransform(transform(image, g), g), image, rtol=0, atol=0)
        moved = transform_pixels(pixels, g, 6)
        marked = torch.zeros(3, 6, 6)
        marked[np.arange(3), pixels[:, 0], pixels[:, 1]] = 1
        assert (transform(marked, g)[np.arange(3), moved[:, 0], moved[:, 1]] == 1).all()
    assert mirrored_channels(9).tolist() == [0, 8, 7, 6, 5, 4, 3, 2, 1]  # +10 deg <-> -10 deg, 0 stays


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


def test_eight_turns_are_exactly_equivariant_to_the_mirror_with_the_turns_reversed(generator) -> None:
    model = SymmetrizedGCTN(GCTN(QUARTER, seed=3).eval(), 8)
    current, goal, picks = _scene(generator)
    flip = lambda x: torch.flip(x, dims=(-1,))  # noqa: E731
    mirrored_picks = torch.as_tensor(mirror_pixels(picks.numpy(), 160))
    with torch.no_grad():
        pick, pick_mirrored = model.pick_logits(current, goal), model.pick_logits(flip(current), flip(goal))
        place = model.place_maps(current, goal, picks)
        place_mirrored = model.place_maps(flip(current), flip(goal), mirrored_picks)
        turned = model.pick_logits(torch.rot90(current, 1, (-2, -1)), torch.rot90(goal, 1, (-2, -1)))
    torch.testing.assert_close(pick_mirrored, flip(pick), atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(turned, torch.rot90(pick, 1, (-2, -1)), atol=1e-5, rtol=1e-5)
    channels, scale = mirrored_channels(place.shape[2]), place.abs().max()  # random weights: tiny logits
    torch.testing.assert_close(place_mirrored / scale, flip(place)[:, :, channels] / scale, atol=1e-5, rtol=0)
    assert not torch.allclose(place_mirrored / scale, flip(place) / scale, atol=1e-2)  # the channels move
    four = SymmetrizedGCTN(GCTN(QUARTER, seed=3).eval(), 4)
    with torch.no_grad():
        alone, alone_mirrored = four.pick_logits(current, goal), four.pick_logits(flip(current), flip(goal))
    assert not torch.allclose(alone_mirrored, flip(alone), atol=1e-3)  # C4 alone is not mirror-equivariant


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
    with pytest.raises(TvfError, match=r"--turns must be 1, 2, 4 \(quarter turns .*\) or 8"):
        symmetrized(plain, 3)
    model = SymmetrizedGCTN(plain, 4)
    with pytest.raises(ValueError, match="expected goal features"):
        model.place_maps(torch.zeros(1, 4, 160, 160), None, torch.zeros(1, 1, 2, dtype=torch.int64),
                         plain.goal_features(torch.zeros(1, 4, 160, 160)))  # fmt: skip
