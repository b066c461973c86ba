"""Picks moved to the centre of the block face under them (``--centre-picks``)."""

from __future__ import annotations

import math

import torch
from model_scenes import draw_blocks

from tvf.models.gctn import GCTN
from tvf.models.goal_mask import GoalMaskedGCTN
from tvf.models.images import heights_of, to_rgbh
from tvf.models.pick_centre import CentredPickGCTN, centring_picks, face_centres
from tvf.models.presets import SMOKE
from tvf.models.symmetry import SymmetrizedGCTN

QUARTER = SMOKE.replace(symmetry=4, pad_features=True)


def _turned_block(height: torch.Tensor, centre: tuple[float, float], yaw: float, top: float) -> None:
    """Draws a 4 cm (12.8 px) square turned by ``yaw`` at ``centre`` (row, col) into ``height``."""
    rows, cols = torch.meshgrid(torch.arange(160.0), torch.arange(160.0), indexing="ij")
    dr, dc = rows - centre[0], cols - centre[1]
    u = math.cos(yaw) * dc + math.sin(yaw) * dr
    v = -math.sin(yaw) * dc + math.cos(yaw) * dr
    height[(u.abs() <= 6.4) & (v.abs() <= 6.4)] = top


def test_a_pick_off_a_blocks_middle_moves_to_the_middle_of_its_face() -> None:
    height = torch.zeros(1, 160, 160)
    _turned_block(height[0], (50.0, 70.0), 0.0, 0.04)
    _turned_block(height[0], (110.0, 40.0), math.radians(30), 0.08)  # a turned block, a layer up
    picks = torch.tensor([[[46, 66], [54, 73], [106, 44], [110, 40]]])
    moved = face_centres(height, picks)
    assert moved[0, :2].tolist() == [[50, 70], [50, 70]]
    assert moved[0, 2:].tolist() == [[110, 40], [110, 40]]


def test_a_pick_that_is_not_on_one_blocks_face_stays() -> None:
    height = torch.zeros(2, 160, 160)
    height[0, 20:27, 20:25] = 0.04  # a speck, far smaller than a face
    height[0, 60:73, 60:99] = 0.04  # three faces merged into one reading
    height[1, 40:140, 40:140] = 0.04  # a wide top running out of the window
    picks = torch.tensor([[[22, 22], [66, 62]], [[130, 130], [5, 150]]])  # the last on the bare table
    assert torch.equal(face_centres(height, picks), picks)


def test_faces_are_read_per_state_and_at_the_image_border() -> None:
    height = torch.zeros(2, 160, 160)
    _turned_block(height[0], (80.0, 80.0), 0.0, 0.04)
    _turned_block(height[1], (7.0, 153.0), 0.0, 0.04)  # a block touching the image's corner
    picks = torch.tensor([[[76, 84]], [[3, 157]]])
    moved = face_centres(height, picks)
    assert moved[0, 0].tolist() == [80, 80] and moved[1, 0].tolist() == [7, 153]
    assert face_centres(height, torch.zeros(2, 0, 2, dtype=torch.int64)).shape == (2, 0, 2)


def test_the_centring_gctn_acts_from_its_blocks_middle_with_the_wrapped_maps() -> None:
    gctn = GCTN(QUARTER, seed=3).eval()
    centred = centring_picks(gctn, True)
    assert isinstance(centred, CentredPickGCTN) and centring_picks(gctn, False) is gctn
    current, goal = to_rgbh(*draw_blocks([(30, 30), (90, 100)])), to_rgbh(*draw_blocks([(80, 80)]))
    picks = torch.tensor([[[27, 33]]])
    with torch.no_grad():
        assert torch.equal(centred.pick_logits(current, goal), gctn.pick_logits(current, goal))
        assert torch.equal(centred.place_maps(current, goal, picks), gctn.place_maps(current, goal, picks))
        pick, place, rot, maps = centred.act(current, goal)
        plain_pick = gctn.act(current, goal)[0]
    assert pick[0].tolist() in ([30, 30], [90, 100])  # a block's middle, wherever the GCTN picked it
    assert torch.equal(face_centres(heights_of(current), plain_pick[:, None])[:, 0], pick)
    with torch.no_grad():
        expected = gctn.place_map(current, goal, pick)
    torch.testing.assert_close(maps["place"], expected, rtol=0, atol=0)  # the place map at the moved pick
    assert torch.equal(gctn.pick_pixels(current, picks), picks)  # the plain GCTN keeps its picks


def test_the_picks_are_centred_under_the_symmetrising_and_masking_wrappers() -> None:
    gctn = SymmetrizedGCTN(CentredPickGCTN(GoalMaskedGCTN(GCTN(QUARTER, seed=3).eval())), 8)
    current = to_rgbh(*draw_blocks([(30, 30)]))
    assert gctn.pick_pixels(current, torch.tensor([[[25, 34]]])).tolist() == [[[30, 30]]]
    assert SymmetrizedGCTN(GCTN(QUARTER, seed=3).eval(), 4).pick_pixels(current, torch.tensor([[[25, 34]]])
                                                                      ).tolist() == [[[25, 34]]]  # fmt: skip
