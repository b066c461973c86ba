"""The rigid-body foresight: the picked block moved on the height map, without a network."""

import math

import numpy as np
import pytest
import torch

from tvf.errors import TvfError
from tvf.geometry import pixel_to_world, world_to_pixel, wrap_angle
from tvf.models.images import from_rgbh, heights_of, to_rgbh
from tvf.planning.rigid import RigidForesight, picked_block, resting
from tvf.policies import PolicySpec, make_policy, needs_env, resolved_settings
from tvf.sim.factory import sim_env
from tvf.tasks import get_task

BLOCK = 0.04
CELL = 0.005
HALF = 6  # a 13 px block
TABLE, BROWN, RED = (200, 200, 200), (120, 80, 40), (220, 30, 30)
FORESIGHT = RigidForesight()
FALLS = RigidForesight(falls=True)


def _scene(blocks=(), cells=()) -> torch.Tensor:
    """A normalised RGB-H scene (1, 4, 160, 160): 15 px base cells (row, col) and 13 px blocks (row, col,
    top height), drawn in order."""
    color = np.zeros((1, 160, 160, 3), np.float32) + TABLE
    height = np.zeros((1, 160, 160), np.float32)
    for r, c in cells:
        color[0, r - 7 : r + 8, c - 7 : c + 8] = BROWN
        height[0, r - 7 : r + 8, c - 7 : c + 8] = CELL
    for r, c, top in blocks:
        color[0, r - HALF : r + HALF + 1, c - HALF : c + HALF + 1] = RED
        height[0, r - HALF : r + HALF + 1, c - HALF : c + HALF + 1] = top
    return to_rgbh(color, height)


def _move(scene, pick, place, yaw=0.0, foresight=FORESIGHT):
    out = foresight.predict_rgbh(scene, torch.tensor([pick]), torch.tensor([place]), torch.tensor([yaw]))
    color, height = from_rgbh(out)
    return color[0].numpy(), height[0].numpy()


def test_a_block_moved_to_the_table_leaves_the_table_behind():
    color, height = _move(_scene([(40, 40, BLOCK)]), (40, 40), (100, 120))
    assert height[100, 120] == pytest.approx(BLOCK, abs=1e-4)
    assert height[40, 40] == pytest.approx(0.0, abs=1e-4)
    np.testing.assert_allclose(color[100, 120], RED, atol=0.5)
    np.testing.assert_allclose(color[40, 40], TABLE, atol=0.5)
    moved = np.abs(height - BLOCK) < 1e-3
    assert moved.sum() == 13 * 13 and moved[100 - HALF : 100 + HALF + 1, 120 - HALF : 120 + HALF + 1].all()


def test_a_block_lands_on_the_highest_surface_under_it():
    scene = _scene([(40, 40, BLOCK), (100, 100, 2 * BLOCK)])
    _, height = _move(scene, (40, 40), (100, 100))
    assert height[100, 100] == pytest.approx(3 * BLOCK, abs=1e-4)
    _, beside = _move(scene, (40, 40), (100, 108))  # half over the tower: lands on its top, falls not drawn
    assert beside[100, 108] == pytest.approx(3 * BLOCK, abs=1e-4)


def test_with_falls_a_block_whose_centre_overhangs_tips_off_beside_the_tower():
    scene = _scene([(40, 40, BLOCK), (100, 100, 2 * BLOCK)])  # the tower spans columns 94-106
    color, height = _move(scene, (40, 40), (100, 108), foresight=FALLS)  # centre 2 px past its edge
    assert not (np.abs(height - 3 * BLOCK) < 1e-3).any()
    rows, cols = np.nonzero(np.abs(height - BLOCK) < 1e-3)  # on the table, clear of the tower
    assert len(rows) == 13 * 13 and cols.min() > 106 and rows.mean() == pytest.approx(100, abs=0.5)
    np.testing.assert_allclose(color[100, cols.max()], RED, atol=0.5)
    assert height[100, 100] == pytest.approx(2 * BLOCK, abs=1e-4)  # the tower stands
    _, left = _move(scene, (40, 40), (100, 92), foresight=FALLS)  # past the other edge: tips the other way
    assert np.nonzero(np.abs(left - BLOCK) < 1e-3)[1].max() < 94
    _, held = _move(scene, (40, 40), (100, 105), foresight=FALLS)  # centre 1 px inside the edge: it rests
    assert held[100, 105] == pytest.approx(3 * BLOCK, abs=1e-4)


def test_with_falls_a_block_across_two_towers_rests_and_the_experts_places_stay():
    bridge = _scene([(40, 40, BLOCK), (100, 94, 2 * BLOCK), (100, 108, 2 * BLOCK)])  # a 1 px gap between
    _, height = _move(bridge, (40, 40), (100, 101), foresight=FALLS)
    assert (np.abs(height - 3 * BLOCK) < 1e-3).sum() == 13 * 13
    scene = _scene([(40, 40, BLOCK), (100, 100, 2 * BLOCK)])
    for place in [(100, 100), (96, 103), (120, 40)]:
        drawn, plain = _move(scene, (40, 40), place, foresight=FALLS), _move(scene, (40, 40), place)
        np.testing.assert_array_equal(drawn[1], plain[1])
        np.testing.assert_array_equal(drawn[0], plain[0])


def test_resting_reads_the_support_under_a_footprint():
    surface = torch.zeros(2, 40, 40)
    surface[:, 10:30, 10:20] = 2 * BLOCK  # a ledge: columns 10-19
    footprint = torch.zeros(2, 40, 40, dtype=torch.bool)
    footprint[0, 14:27, 8:21] = True  # centre column 14: over the ledge
    footprint[1, 14:27, 16:29] = True  # centre column 22: past its edge
    rests, away = resting(footprint, surface)
    assert rests.tolist() == [True, False]
    assert away[0].tolist() == [0.0, 0.0] and away[1].tolist() == pytest.approx([0.0, 1.0], abs=1e-6)
    empty = resting(torch.zeros(1, 40, 40, dtype=torch.bool), surface[:1])[0]
    assert empty.tolist() == [True]


def test_the_uncovered_surface_shows_the_level_beneath():
    on_cell = _scene([(40, 40, CELL + BLOCK), (80, 80, 2 * BLOCK)], cells=[(40, 40), (120, 120)])
    color, height = _move(on_cell, (40, 40), (120, 40))
    assert height[40, 40] == pytest.approx(CELL, abs=1e-4)
    np.testing.assert_allclose(color[40, 40], BROWN, atol=0.5)
    color, height = _move(on_cell, (80, 80), (120, 40))  # the top block of a tower of two
    assert height[80, 80] == pytest.approx(BLOCK, abs=1e-4)
    np.testing.assert_allclose(color[80, 80], RED, atol=0.5)


def test_only_the_picked_block_moves_not_its_neighbours():
    scene = _scene([(40, 40, BLOCK), (40, 56, BLOCK)])  # a 3 px gap between them
    block = picked_block(heights_of(scene), torch.tensor([[40, 40]]))[0]
    assert block.sum() == 13 * 13 and not block[40, 56 - HALF :].any()
    _, height = _move(scene, (40, 40), (120, 120))
    assert height[40, 56] == pytest.approx(BLOCK, abs=1e-4) and height[40, 40] == pytest.approx(0, abs=1e-4)


def test_a_pick_on_nothing_moves_nothing():
    scene = _scene([(40, 40, BLOCK)], cells=[(100, 100)])
    for pick in [(80, 80), (100, 100)]:  # the table, a base cell
        out = FORESIGHT.predict_rgbh(scene, torch.tensor([pick]), torch.tensor([[40, 40]]), torch.zeros(1))
        torch.testing.assert_close(out, scene)


def test_an_off_centre_pick_turns_the_block_about_the_pick():
    """Content moves as p' = R(yaw)(p - pick) + place in (col, row): a block whose centre is 5 px right
    of the pick, turned a quarter, ends 5 px below the place (rows grow downwards)."""
    scene = _scene([(40, 45, BLOCK)])
    _, height = _move(scene, (40, 40), (100, 100), math.pi / 2)
    rows, cols = np.nonzero(np.abs(height - BLOCK) < 1e-3)
    assert (rows.mean(), cols.mean()) == pytest.approx((105, 100), abs=0.5)


@pytest.mark.parametrize("foresight", [FORESIGHT, FALLS], ids=["rigid", "rigid-falls"])
def test_a_batch_moves_each_image_alone(foresight):
    a, b = _scene([(40, 40, BLOCK)]), _scene([(100, 100, BLOCK), (40, 40, BLOCK)])
    c = _scene([(40, 40, BLOCK), (100, 100, 2 * BLOCK)])
    picks = torch.tensor([[40, 40], [100, 100], [40, 40]])
    places = torch.tensor([[120, 120], [40, 40], [100, 108]])  # the third falls with falls drawn
    out = foresight.predict_rgbh(torch.cat([a, b, c]), picks, places, torch.zeros(3))
    for i, scene in enumerate([a, b, c]):
        one = foresight.predict_rgbh(scene, picks[i : i + 1], places[i : i + 1], torch.zeros(1))
        torch.testing.assert_close(out[i : i + 1], one)
    assert heights_of(out)[1, 40, 40] == pytest.approx(2 * BLOCK, abs=1e-4)


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="RGB-H"):
        FORESIGHT.predict_rgbh(
            torch.zeros(1, 3, 160, 160), torch.tensor([[1, 1]]), torch.tensor([[2, 2]]), [0.0]
        )
    with pytest.raises(ValueError, match="outside"):
        FORESIGHT.predict_rgbh(_scene(), torch.tensor([[1, 170]]), torch.tensor([[2, 2]]), [0.0])


@pytest.mark.parametrize("foresight", [FORESIGHT, FALLS], ids=["rigid", "rigid-falls"])
def test_it_foresees_the_experts_moves_in_the_simulator(foresight):
    """Along three of the oracle's moves in the real simulator, the rigid images stay within a few
    millimetres of the real ones on the pixels that changed (copying the input misses by a block)."""
    env = sim_env(get_task("stack-stair"))
    obs, _ = env.reset(seed=5)
    imagined = real = to_rgbh(obs["color"][None], obs["height"][None])
    for _ in range(3):
        action = env.oracle_action()
        pick, place = world_to_pixel(action[:1, :2]), world_to_pixel(action[1:, :2])
        yaw = torch.tensor([float(wrap_angle(action[1, 3] - action[0, 3]))])
        imagined = foresight.predict_rgbh(imagined, torch.as_tensor(pick), torch.as_tensor(place), yaw)
        before = heights_of(real)[0]
        obs, *_ = env.step(action)
        real = to_rgbh(obs["color"][None], obs["height"][None])
        changed = (heights_of(real)[0] - before).abs() > 0.005
        error = (heights_of(imagined)[0] - heights_of(real)[0]).abs()
        assert changed.sum() > 100
        assert error[changed].mean() < 0.006, float(error[changed].mean())
        assert error.mean() < 0.001


def test_with_falls_it_foresees_a_real_topple_in_the_simulator():
    """The oracle's second move of stack-stair seed 5 puts a block on a block; put 9 px to the side its
    centre overhangs, and in the simulator it topples to the level below. The rigid image keeps it on
    the tower (a block off); with falls it lands beside the tower, within a few millimetres."""
    env = sim_env(get_task("stack-stair"))
    obs, _ = env.reset(seed=5)
    obs, *_ = env.step(env.oracle_action())
    action = env.oracle_action()
    pick, place = world_to_pixel(action[:1, :2]), world_to_pixel(action[1:, :2]) + np.array([[0, 9]])
    action[1, :2] = pixel_to_world(place)[0, :2]
    before = to_rgbh(obs["color"][None], obs["height"][None])
    yaw = torch.tensor([float(wrap_angle(action[1, 3] - action[0, 3]))])
    obs, *_ = env.step(action)
    real = heights_of(to_rgbh(obs["color"][None], obs["height"][None]))[0]
    tower = float(heights_of(before)[0][tuple(place[0] - np.array([0, 9]))])
    assert tower > BLOCK and float(real[tuple(place[0])]) < tower + BLOCK / 2  # not on the block: it fell
    changed = (real - heights_of(before)[0]).abs() > 0.005
    errors = []
    for foresight in (FORESIGHT, FALLS):
        imagined = foresight.predict_rgbh(before, torch.as_tensor(pick), torch.as_tensor(place), yaw)
        errors.append(float((heights_of(imagined)[0] - real).abs()[changed].mean()))
    assert errors[0] > 0.015 and errors[1] < 0.008, errors


def test_a_tvf_method_plans_with_it_and_no_vf():
    env = sim_env(get_task("stack-stair"))
    obs, info = env.reset(seed=2)
    policy = make_policy(PolicySpec("tvf-large-no-image-rules", foresight="rigid", support_check=True), env)
    assert isinstance(policy.search.vf, RigidForesight)
    action = policy.act(obs, info["goal"])
    assert action.shape == (2, 4) and np.isfinite(action).all()
    assert resolved_settings(PolicySpec("tvf-large", foresight="rigid"))["foresight"] == "rigid"
    falls = make_policy(PolicySpec("tvf-large-no-image-rules", foresight="rigid-falls"), env)
    assert isinstance(falls.search.vf, RigidForesight) and falls.search.vf.falls
    assert not policy.search.vf.falls
    assert np.isfinite(falls.act(obs, info["goal"])).all()
    with pytest.raises(TvfError, match="drop --vf"):  # a VF it would ignore is refused, not dropped silently
        make_policy(PolicySpec("tvf-large", vf="runs/vf", foresight="rigid-falls"), env)
    assert not needs_env(PolicySpec("tvf-large", foresight="rigid"))  # no simulator: a robot can run it
