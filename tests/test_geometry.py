import math

import numpy as np
import torch
from hypothesis import given
from hypothesis import strategies as st

from tvf.geometry import (
    WORKSPACE,
    bin_to_yaw,
    pixel_in_image,
    pixel_to_world,
    rotate_pixels,
    rotate_xy,
    se2_output_to_input,
    warp_images,
    world_to_pixel,
    wrap_symmetric,
    yaw_to_bin,
)

rows = st.integers(0, WORKSPACE.rows - 1)
cols = st.integers(0, WORKSPACE.cols - 1)
xs = st.floats(WORKSPACE.x_min, WORKSPACE.x_max, exclude_max=True)
ys = st.floats(WORKSPACE.y_min, WORKSPACE.y_max, exclude_max=True)
angles = st.floats(-10.0, 10.0)


def test_image_is_160_square_with_rows_along_y():
    assert WORKSPACE.shape == (160, 160)
    assert world_to_pixel([0.25, -0.25]).tolist() == [0, 0]
    assert world_to_pixel([0.7499, -0.25]).tolist() == [0, 159]  # x -> columns
    assert world_to_pixel([0.25, 0.2499]).tolist() == [159, 0]  # y -> rows


@given(rows, cols)
def test_pixel_world_pixel_is_exact(r, c):
    assert world_to_pixel(pixel_to_world([r, c])).tolist() == [r, c]


@given(xs, ys)
def test_world_pixel_world_within_half_a_pixel(x, y):
    back = pixel_to_world(world_to_pixel([x, y]))
    assert np.all(np.abs(back - [x, y]) <= WORKSPACE.pixel_size / 2 + 1e-12)
    assert pixel_in_image(world_to_pixel([x, y]))


@given(rows, cols, angles, rows, cols)
def test_pixel_rotation_is_the_image_of_world_rotation(r, c, yaw, cr, cc):
    rotated = rotate_pixels([r, c], yaw, [cr, cc])
    world_centre = pixel_to_world([cr, cc])
    expected = rotate_xy(pixel_to_world([r, c]) - world_centre, yaw) + world_centre
    assert np.allclose(pixel_to_world(rotated), expected, atol=1e-9)


@given(st.integers(0, 35), st.sampled_from([8, 12, 36]))
def test_rotation_bins_round_trip(i, n):
    i = i % n
    assert yaw_to_bin(bin_to_yaw(i, n), n) == i


@given(angles)
def test_bin_is_nearest(yaw):
    step = 2 * math.pi / 36
    err = wrap_symmetric(bin_to_yaw(yaw_to_bin(yaw, 36), 36) - yaw, 2 * math.pi)
    assert abs(err) <= step / 2 + 1e-9


def test_warp_turns_content_by_the_world_yaw():
    """A marked pixel moves where rotate_pixels says (a quarter turn is exact on the grid)."""
    img = torch.zeros(1, 1, 160, 160)
    img[0, 0, 50, 70] = 1.0
    centre = torch.tensor([[80.0, 80.0]])
    out = warp_images(img, se2_output_to_input(torch.tensor([math.pi / 2]), centre))
    expected = np.round(rotate_pixels([50, 70], math.pi / 2, [80, 80])).astype(int)
    assert out[0, 0].nonzero().tolist() == [expected.tolist()]


def test_warp_with_shift_translates():
    img = torch.zeros(1, 1, 160, 160)
    img[0, 0, 10, 20] = 1.0
    m = se2_output_to_input(torch.tensor([0.0]), torch.tensor([[0.0, 0.0]]), torch.tensor([[5.0, -3.0]]))
    out = warp_images(img, m)
    assert out[0, 0].nonzero().tolist() == [[15, 17]]
