"""Imagined heights snapped to the resting levels: the levels, the nearest one, which pixels move."""

import pytest
import torch

from tvf.models.images import MAX_HEIGHT, heights_of, to_rgbh
from tvf.planning.levels import nearest_level, resting_levels, snap_heights
from tvf.tasks import BLOCK_SIZE, CELL_THICKNESS


def test_the_levels_are_the_table_a_cell_and_stacks_on_either():
    levels = resting_levels()
    first = [0.0, CELL_THICKNESS, BLOCK_SIZE, BLOCK_SIZE + CELL_THICKNESS]
    assert levels[:4].tolist() == pytest.approx(first)
    assert torch.all(levels.diff() > 0)
    assert levels[-1] <= MAX_HEIGHT
    assert resting_levels(0.05).tolist() == pytest.approx([0.0, 0.005, 0.04, 0.045])


@pytest.mark.parametrize(
    ("height", "level"),
    [(-0.01, 0.0), (0.0024, 0.0), (0.0026, 0.005), (0.022, 0.005), (0.023, 0.04), (0.0431, 0.045),
     (0.064, 0.08), (0.5, 0.28)],
)  # fmt: skip
def test_each_height_goes_to_the_nearest_level(height: float, level: float):
    snapped = nearest_level(torch.tensor([height]), resting_levels())
    assert snapped.item() == pytest.approx(level)


def _image(heights: list[float]) -> torch.Tensor:
    """A 1 x n RGB-H image with these heights and a colour ramp."""
    n = len(heights)
    color = torch.linspace(0, 255, 3 * n).reshape(1, n, 3)
    return to_rgbh(color, torch.tensor([heights]))


def test_only_the_pixels_the_vf_moved_are_snapped_and_colour_is_kept():
    parent = _image([0.0397, 0.0, 0.0, 0.045, 0.0])
    imagined = _image([0.0401, 0.031, 0.0062, 0.012, 0.0])  # a real block top, blur, a lifted block
    imagined[:, :3] += 0.5
    out = snap_heights(imagined, parent)
    # within a millimetre of the parent: the VF's height (an off-level real surface is not moved)
    assert heights_of(out)[0, 0].tolist() == pytest.approx([0.0401, 0.04, 0.005, 0.005, 0.0], abs=1e-6)
    assert torch.equal(out[:, :3], imagined[:, :3])
    assert heights_of(imagined)[0, 0, 1].item() == pytest.approx(0.031, abs=1e-6)  # the input is not changed


def test_a_height_further_than_the_tolerance_from_every_level_is_kept():
    parent, imagined = _image([0.0, 0.0]), _image([0.022, 0.039])
    out = snap_heights(imagined, parent, tolerance=0.005)
    assert heights_of(out)[0, 0].tolist() == pytest.approx([0.022, 0.04], abs=1e-6)


def test_images_and_parents_must_match():
    with pytest.raises(ValueError, match="differ in shape"):
        snap_heights(_image([0.0, 0.0]), _image([0.0]))
