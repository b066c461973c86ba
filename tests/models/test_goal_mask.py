"""The goal-difference mask: where it lets the GCTN pick and place, and that it commutes with the turns."""

from __future__ import annotations

import pytest
import torch
from model_scenes import BLOCK, draw_blocks

from tvf.models.gctn import GCTN
from tvf.models.goal_mask import MASKED_LOGIT, GoalMaskedGCTN, goal_masked, pick_allowed, place_allowed
from tvf.models.images import to_rgbh
from tvf.models.presets import SMOKE
from tvf.models.symmetry import SymmetrizedGCTN

QUARTER = SMOKE.replace(symmetry=4, pad_features=True)
LOOSE, PLACED, TARGET = (30, 30), (80, 80), (80, 110)


def _scene() -> tuple[torch.Tensor, torch.Tensor]:
    """A loose block and a placed one; the goal has the placed one and the loose one at TARGET."""
    current = to_rgbh(*draw_blocks([LOOSE, PLACED]))
    goal = to_rgbh(*draw_blocks([PLACED, TARGET]))
    return current, goal


def _footprint(centre: tuple[int, int]) -> torch.Tensor:
    mask = torch.zeros(160, 160, dtype=torch.bool)
    half = BLOCK // 2
    mask[centre[0] - half : centre[0] + half + 1, centre[1] - half : centre[1] + half + 1] = True
    return mask


def test_pick_where_the_scene_has_a_block_the_goal_lacks_and_place_where_the_goal_has_one() -> None:
    current, goal = _scene()
    assert torch.equal(pick_allowed(current, goal)[0], _footprint(LOOSE))  # not the placed block
    assert torch.equal(place_allowed(current, goal)[0], _footprint(TARGET))


def test_a_state_with_nothing_to_do_keeps_every_pixel() -> None:
    current, _ = _scene()
    assert pick_allowed(current, current).all() and place_allowed(current, current).all()
    flat = to_rgbh(*draw_blocks([]))  # per state: the first has work, the second none
    both = torch.cat([current, flat])
    allowed = pick_allowed(both, torch.cat([flat, flat]))
    assert torch.equal(allowed[0], _footprint(LOOSE) | _footprint(PLACED)) and allowed[1].all()


def test_the_masked_gctn_keeps_its_logits_inside_the_mask_and_pushes_the_rest_down() -> None:
    gctn = GCTN(QUARTER, seed=3).eval()
    masked = goal_masked(gctn, True)
    assert isinstance(masked, GoalMaskedGCTN) and goal_masked(gctn, False) is gctn
    current, goal = _scene()
    picks = torch.tensor([[list(LOOSE), list(PLACED)]])
    with torch.no_grad():
        pick, plain_pick = masked.pick_logits(current, goal), gctn.pick_logits(current, goal)
        place, plain_place = masked.place_maps(current, goal, picks), gctn.place_maps(current, goal, picks)
        pick_pixel, place_pixel, _, _ = masked.act(current, goal)
    inside = _footprint(LOOSE)
    torch.testing.assert_close(pick[0][inside], plain_pick[0][inside], rtol=0, atol=0)
    assert (pick[0][~inside] == MASKED_LOGIT).all()
    target = _footprint(TARGET)
    torch.testing.assert_close(place[..., target], plain_place[..., target], rtol=0, atol=0)
    assert (place[..., ~target] == MASKED_LOGIT).all()
    assert inside[tuple(pick_pixel[0].tolist())] and target[tuple(place_pixel[0].tolist())]


def test_masking_commutes_with_the_turns_and_mirrors() -> None:
    gctn = GCTN(QUARTER, seed=3).eval()
    current, goal = _scene()
    picks = torch.tensor([[list(LOOSE)]])
    masked_then_averaged = SymmetrizedGCTN(GoalMaskedGCTN(gctn), 8)
    averaged = SymmetrizedGCTN(gctn, 8)
    with torch.no_grad():
        pick = masked_then_averaged.pick_logits(current, goal)
        place = masked_then_averaged.place_maps(current, goal, picks, averaged.goal_features(goal))
        plain_pick = averaged.pick_logits(current, goal)
        plain_place = averaged.place_maps(current, goal, picks)
    loose, target = _footprint(LOOSE), _footprint(TARGET)
    torch.testing.assert_close(pick[0][loose], plain_pick[0][loose], atol=1e-6, rtol=1e-6)
    assert (pick[0][~loose] == MASKED_LOGIT).all()
    torch.testing.assert_close(place[..., target], plain_place[..., target], atol=1e-6, rtol=1e-6)
    assert (place[..., ~target] == MASKED_LOGIT).all()


def test_the_masked_gctn_refuses_features_without_the_goal_image() -> None:
    masked = GoalMaskedGCTN(GCTN(QUARTER, seed=3).eval())
    current, goal = _scene()
    with pytest.raises(ValueError, match="needs the goal image"):
        masked.place_maps(current, None, torch.tensor([[list(LOOSE)]]), masked.goal_features(goal))
