"""Pixels and rotation bins -> robot actions: the conversion every learned policy executes, checked on
numbers and by a round trip through the simulator (oracle -> (pixel, bin) -> bin_action -> success)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tvf.geometry import PIXEL_SIZE, WORKSPACE, bin_to_yaw, pixel_to_world, world_to_pixel, yaw_to_bin
from tvf.planning.actions import FOOTPRINT_PX, bin_action, pixels_to_action, surface_height
from tvf.tasks import BLOCK_SIZE

R = 36


def flat_height(value: float = 0.0) -> np.ndarray:
    return np.full(WORKSPACE.shape, value, dtype=np.float32)


def test_pixels_become_pixel_centres_with_the_surface_heights():
    height = flat_height(0.005)
    height[40, 70] = 0.045  # the top of a block under the pick
    height[100, 30 + FOOTPRINT_PX // 2] = 0.085  # the edge of a block under the place footprint
    action = pixels_to_action(np.array([40, 70]), np.array([100, 30]), 0.25, height)
    assert action.shape == (2, 4) and action.dtype == np.float64
    assert action[0].tolist() == pytest.approx(
        [0.25 + 70.5 * PIXEL_SIZE, -0.25 + 40.5 * PIXEL_SIZE, 0.045, 0.0]
    )
    x, y = pixel_to_world(np.array([100, 30]))
    assert action[1].tolist() == pytest.approx([x, y, 0.085 + BLOCK_SIZE, 0.25])


def test_the_place_height_ignores_surfaces_outside_the_footprint_and_stays_in_range():
    height = flat_height()
    height[100, 30 + FOOTPRINT_PX // 2 + 1] = 0.085  # one pixel beyond the footprint
    assert pixels_to_action(np.array([0, 0]), np.array([100, 30]), 0.0, height)[1, 2] == pytest.approx(
        BLOCK_SIZE
    )
    assert surface_height(height, np.array([100, 30 + 1])) == pytest.approx(0.085)
    tall = flat_height(0.27)
    assert pixels_to_action(np.array([5, 5]), np.array([150, 150]), 0.0, tall)[1, 2] == WORKSPACE.z_max
    assert surface_height(height, np.array([0, 0])) == 0.0  # a window clipped at the image corner


@pytest.mark.parametrize("direction", [(-1, 0), (1, 0), (0, -1), (0, 1)])
def test_the_footprint_reaches_half_a_window_on_each_side_and_no_further(direction: tuple[int, int]):
    half = FOOTPRINT_PX // 2
    for reach, expected in ((half, 0.085), (half + 1, 0.0)):
        height = flat_height()
        height[80 + reach * direction[0], 80 + reach * direction[1]] = 0.085
        assert surface_height(height, np.array([80, 80])) == pytest.approx(expected), reach


def test_a_footprint_clipped_at_the_map_edge_still_covers_the_first_row_and_column():
    height = flat_height()
    height[0, 80] = 0.045
    height[120, 0] = 0.065
    assert surface_height(height, np.array([3, 80])) == pytest.approx(0.045)
    assert surface_height(height, np.array([120, 2])) == pytest.approx(0.065)
    off = np.array([WORKSPACE.shape[0] + FOOTPRINT_PX, WORKSPACE.shape[1] + FOOTPRINT_PX])
    assert surface_height(flat_height(0.1), off) == 0.0  # a window wholly off the map: the floor


@pytest.mark.parametrize(
    "rot_bin, degrees", [(0, 0.0), (3, 30.0), (9, 90.0), (18, -180.0), (27, -90.0), (33, -30.0), (35, -10.0)]
)
def test_bin_action_turns_by_the_bins_counter_clockwise_yaw(rot_bin: int, degrees: float):
    height = flat_height()
    action = bin_action(np.array([10, 20]), np.array([30, 40]), rot_bin, R, height)
    assert math.degrees(action[1, 3]) == pytest.approx(degrees)
    assert action[0, 3] == 0.0
    expected = pixels_to_action(np.array([10, 20]), np.array([30, 40]), float(bin_to_yaw(rot_bin, R)), height)
    assert np.array_equal(action, expected)


def test_bins_and_yaws_round_trip():
    for b in range(R):
        assert yaw_to_bin(bin_to_yaw(b, R), R) == b
    assert yaw_to_bin(math.radians(24.9), R) == 2 and yaw_to_bin(math.radians(-24.9), R) == R - 2


def test_oracle_actions_through_pixels_and_bins_still_build_the_structure():
    """What a learned policy does with a perfect map: the oracle's action quantised to (pixel, bin) and
    turned back by bin_action must still finish the structure. Seed 1 of stack-stair needs turns of
    -28, +15 and +30 degrees, so a flipped yaw sign (or a bin read the wrong way) fails here."""
    from tvf.sim.env import TvfEnv

    env = TvfEnv("stack-stair")
    try:
        obs, _ = env.reset(seed=1)
        info, turns = {"success": False}, []
        for _ in range(env.task.horizon):
            oracle = env.oracle_action()
            pick, place = world_to_pixel(oracle[0, :2]), world_to_pixel(oracle[1, :2])
            rot_bin = int(yaw_to_bin(oracle[1, 3] - oracle[0, 3], R))
            action = bin_action(pick, place, rot_bin, R, obs["height"])
            assert np.abs(action[:, :2] - oracle[:, :2]).max() <= PIXEL_SIZE  # quantised to a pixel
            assert abs(action[1, 3] - oracle[1, 3]) <= math.radians(5) + 1e-9  # ... and to a 10 degree bin
            turns.append(math.degrees(oracle[1, 3]))
            obs, _, terminated, _, info = env.step(action)
            if terminated:
                break
        assert max(abs(t) for t in turns) > 15  # a wrong sign would miss the 15 degree tolerance
        assert info["success"], info
    finally:
        env.close()
