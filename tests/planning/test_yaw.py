"""Block yaws read from a height map, and the place turn they refine (tvf.planning.yaw)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from tvf.geometry import PIXEL_SIZE, bin_to_yaw, pixel_to_world, wrap_symmetric
from tvf.planning.actions import bin_action
from tvf.planning.yaw import MIN_AGREEMENT, MIN_FIT, face_yaw, refined_turn, structure_yaw
from tvf.tasks import BLOCK_SIZE, BLOCK_SYMMETRY

HALF = BLOCK_SIZE / PIXEL_SIZE / 2  # 6.4 px


def draw_block(height: np.ndarray, centre: tuple[float, float], yaw: float, top: float = 0.04) -> None:
    """A 4 cm block's top face at sub-pixel ``centre`` (row, col), turned by the world yaw ``yaw``."""
    rows, cols = np.mgrid[0 : height.shape[0], 0 : height.shape[1]]
    x, y = cols - centre[1], rows - centre[0]  # (col, row) follows (x, y): image angle = world yaw
    u = math.cos(yaw) * x + math.sin(yaw) * y
    v = -math.sin(yaw) * x + math.cos(yaw) * y
    height[(np.abs(u) <= HALF) & (np.abs(v) <= HALF)] = top


def block_scene(centre, yaw, top=0.04) -> np.ndarray:
    height = np.zeros((160, 160), np.float32)
    draw_block(height, centre, yaw, top)
    return height


def yaw_error(a: float, b: float) -> float:
    return abs(float(wrap_symmetric(a - b, BLOCK_SYMMETRY)))


def test_a_blocks_yaw_is_read_to_a_few_degrees_wherever_it_stands():
    rng = np.random.default_rng(0)
    errors = []
    for _ in range(60):
        yaw = rng.uniform(-math.pi, math.pi)
        centre = tuple(rng.uniform(20, 140, 2))
        estimate, fit = face_yaw(block_scene(centre, yaw), np.floor(centre).astype(int))
        assert fit > 0.9 and -math.pi / 4 <= estimate < math.pi / 4
        errors.append(yaw_error(estimate, yaw))
    assert max(errors) < math.radians(3.0) and np.median(errors) < math.radians(1.0)
    # a pixel-centred axis-aligned face: squares within ±3.5° cover the same pixel centres, and the
    # middle of them is read, not an end
    axis_aligned, _ = face_yaw(block_scene((80.0, 80.0), 0.0), np.array([80, 80]))
    assert yaw_error(axis_aligned, 0.0) < math.radians(0.5)


def test_only_the_top_face_at_the_pixel_counts():
    height = block_scene((80.3, 60.6), math.radians(20))
    draw_block(height, (80.3, 79.6), math.radians(20))  # a neighbour at the same height, 1 cm apart
    draw_block(height, (61.3, 60.6), math.radians(40), top=0.08)  # a taller one beside it
    estimate, fit = face_yaw(height, np.array([80, 60]))
    assert fit > 0.9 and yaw_error(estimate, math.radians(20)) < math.radians(3)
    draw_block(height, (80.3, 72.0), math.radians(-30))  # now one that touches it: one face of two
    assert face_yaw(height, np.array([80, 60]))[1] < MIN_FIT


def test_a_face_that_is_not_a_block_is_not_trusted():
    height = np.zeros((160, 160), np.float32)
    height[70:90, 50:90] = 0.04  # a long plank, not a block's top
    assert face_yaw(height, np.array([80, 60]))[1] < MIN_FIT
    goal = block_scene((80.0, 120.0), math.radians(20))
    assert refined_turn(0.3, height, np.array([80, 60]), goal, np.array([80, 120])) == 0.3
    block = block_scene((80.4, 60.3), math.radians(20))
    empty = np.zeros((160, 160), np.float32)  # nothing in the goal there: no direction to read
    assert refined_turn(0.3, block, np.array([80, 60]), empty, np.array([80, 120])) == 0.3


def test_a_structures_yaw_is_read_from_its_edges_even_where_its_blocks_merge():
    rng = np.random.default_rng(1)
    for _ in range(20):
        yaw = rng.uniform(-math.pi, math.pi)
        corner = rng.uniform(50, 90, 2)
        height = np.zeros((160, 160), np.float32)
        for step in ((0, 0), (0, 1), (0, 2), (1, 0), (1, 1)):  # blocks on a 5 cm grid, 1 cm apart
            cell = np.array(step) * 0.05 / PIXEL_SIZE  # (row, col) offsets, turned like (y, x)
            dx, dy = (
                math.cos(yaw) * cell[1] - math.sin(yaw) * cell[0],
                math.sin(yaw) * cell[1] + math.cos(yaw) * cell[0],
            )
            draw_block(height, (corner[0] + dy, corner[1] + dx), yaw)
        merged = ndimage.grey_closing(height, size=4)  # the fused goal image fills the 1 cm gaps
        estimate, agreement = structure_yaw(merged, corner.astype(int))
        assert agreement > MIN_AGREEMENT and yaw_error(estimate, yaw) < math.radians(4)
    assert structure_yaw(np.zeros((160, 160), np.float32), np.array([80, 80])) == (0.0, 0.0)


@pytest.mark.parametrize(
    ("block", "target", "turn", "expected"),
    [
        (7.0, 20.0, 10.0, 13.0),  # the bin's 10° corrected by 3°
        (7.0, 20.0, 30.0, 13.0),  # and a bin two off, by 17°
        (40.0, -40.0, 15.0, 10.0),  # across the symmetry period: -40° is 50°, a 10° turn
        (7.0, 20.0, 40.0, 13.0),  # a 27° correction, more than two bins: the readings still decide
        (20.0, -20.0, 0.0, -40.0),  # and a 40° one (the most a cube's turn can be off is 45°)
        (0.0, 0.0, 96.0, 90.0),  # the GCTN's quarter is kept, its error removed
    ],
)
def test_clear_readings_set_the_turn_modulo_the_cubes_quarter_turn(block, target, turn, expected):
    pick, place = np.array([60, 50]), np.array([100, 110])
    current = block_scene((60.4, 50.7), math.radians(block))
    goal = block_scene((100.2, 110.6), math.radians(target))
    refined = refined_turn(math.radians(turn), current, pick, goal, place)
    # each face is read to a few degrees (a 13 px square): their difference to twice that
    assert refined == pytest.approx(math.radians(expected), abs=math.radians(4))


def test_bin_action_refines_the_turn_only_given_the_goal():
    pick, place = np.array([60, 50]), np.array([100, 110])
    current = block_scene((60.4, 50.7), math.radians(3))
    goal = block_scene((100.2, 110.6), math.radians(21))
    plain = bin_action(pick, place, 2, 36, current)  # bin 2 of 36: 20°
    refined = bin_action(pick, place, 2, 36, current, goal)
    assert plain[1, 3] == pytest.approx(float(bin_to_yaw(2, 36)))
    assert refined[1, 3] == pytest.approx(math.radians(18), abs=math.radians(4))
    np.testing.assert_array_equal(plain[:, :3], refined[:, :3])  # only the turn changes
    np.testing.assert_allclose(refined[1, :2], pixel_to_world(place))
