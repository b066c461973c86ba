"""The goal-difference mask: where it lets the GCTN pick and place, and that it commutes with the turns."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from model_scenes import BLOCK, draw_blocks

from tvf.models.gctn import GCTN
from tvf.models.goal_mask import (
    MASKED_LOGIT,
    PLACE_RULES,
    SEAM_PX,
    GoalMaskedGCTN,
    _box_count,
    _disc,
    _disc_count,
    _disc_max,
    centred_places,
    fitting_places,
    flush_places,
    goal_masked,
    lowest_places,
    mask_of,
    open_cells,
    pick_allowed,
    place_allowed,
    seams_closed,
)
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


def _stacked(blocks: list[tuple[int, int, int]]) -> torch.Tensor:
    """An RGB-H image of 13-pixel blocks at (row, col, layer), drawn bottom layer first."""
    color, height = draw_blocks([])
    half = BLOCK // 2
    for r, c, layer in sorted(blocks, key=lambda b: b[2]):
        window = (slice(r - half, r + half + 1), slice(c - half, c + half + 1))
        height[window] = 0.04 * (layer + 1)
        color[window] = torch.tensor([255.0, 87.0, 89.0])
    return to_rgbh(color, height)


# stack-building's shape: two columns of two blocks 16 px (5 cm) apart and one block bridging them
LEFT, RIGHT, BRIDGE = (80, 64), (80, 80), (80, 72)
BUILDING = [(*LEFT, 0), (*RIGHT, 0), (*LEFT, 1), (*RIGHT, 1), (*BRIDGE, 2)]


def test_bottom_up_places_finish_the_columns_before_the_bridge_across_them() -> None:
    goal = _stacked(BUILDING)
    ground_floor = _stacked(BUILDING[:2])
    gap = place_allowed(ground_floor, goal)[0]
    ordered = place_allowed(ground_floor, goal, rule="bottom-up")[0]
    assert gap[BRIDGE] and not ordered[BRIDGE]  # the bridge would land a layer too low now
    assert ordered[LEFT] and ordered[RIGHT] and (ordered <= gap).all()
    columns = _stacked(BUILDING[:4])
    assert place_allowed(columns, goal, rule="bottom-up")[0][BRIDGE]  # both columns stand: its turn
    empty = _stacked([])  # nothing one block finishes yet (every column is two high): no narrowing
    assert torch.equal(place_allowed(empty, goal, rule="bottom-up"), place_allowed(empty, goal))


def test_centred_places_are_the_middles_of_the_regions_to_fill() -> None:
    current, goal = _scene()
    centred = place_allowed(current, goal, rule="centred")[0]
    rows, cols = torch.nonzero(centred, as_tuple=True)
    assert centred[TARGET] and (rows - TARGET[0]).abs().max() <= 1 and (cols - TARGET[1]).abs().max() <= 1
    assert not centred[TARGET[0], TARGET[1] + 3]  # inside the target cell, but off its middle
    both = centred_places(torch.ones(2, 160, 160, dtype=torch.bool))  # nothing to fill: all but the rim
    assert both[:, 80, 80].all() and not both[:, 0, 0].any()


def test_ordered_places_are_centred_and_bottom_up_and_an_unknown_rule_is_refused() -> None:
    goal, ground_floor = _stacked(BUILDING), _stacked(BUILDING[:2])
    ordered = place_allowed(ground_floor, goal, rule="ordered")[0]
    assert ordered[LEFT] and ordered[RIGHT] and not ordered[BRIDGE]
    assert (ordered <= place_allowed(ground_floor, goal, rule="centred")[0]).all()
    masked = GoalMaskedGCTN(GCTN(QUARTER, seed=3).eval(), places="ordered")
    with torch.no_grad():
        _, place, _, _ = masked.act(ground_floor, goal)
    assert ordered[tuple(place[0].tolist())]
    with pytest.raises(ValueError, match="unknown place rule 'tallest'; choose one of gap, centred"):
        place_allowed(ground_floor, goal, rule="tallest")


def test_a_lower_centred_share_keeps_more_of_each_region_around_its_middle() -> None:
    current, goal = _scene()
    shares = (1.0, 0.9, 0.75, 0.6)
    kept = [place_allowed(current, goal, rule="centred", share=s)[0] for s in shares]
    counts = [int(k.sum()) for k in kept]
    assert counts == sorted(counts) and counts[0] < counts[-1]  # each lower share a superset, larger
    for narrow, wide in zip(kept, kept[1:], strict=False):
        assert (narrow <= wide).all()
    # a pixel off the middle loses 1/13 of its footprint a step: 0.75 keeps three steps either way
    assert kept[2][TARGET[0], TARGET[1] + 3] and not kept[2][TARGET[0], TARGET[1] + 4]
    assert (kept[-1] <= place_allowed(current, goal)[0]).all()  # still inside the gap rule's places
    with pytest.raises(ValueError, match=r"the centred share must be in \(0, 1\], got 0"):
        GoalMaskedGCTN(GCTN(QUARTER, seed=3).eval(), places="ordered", share=0.0)


def test_the_mask_under_a_symmetrising_wrapper_is_found_with_its_settings() -> None:
    plain = GCTN(QUARTER, seed=3).eval()
    masked = goal_masked(plain, True, places="ordered", share=0.75)
    assert mask_of(SymmetrizedGCTN(masked, 4)) is masked and mask_of(masked) is masked
    assert mask_of(plain) is None and mask_of(SymmetrizedGCTN(plain, 4)) is None
    goal, ground_floor = _stacked(BUILDING), _stacked(BUILDING[:2])
    expected = place_allowed(ground_floor, goal, rule="ordered", share=0.75)
    assert torch.equal(masked.allowed_places(ground_floor, goal), expected)
    assert torch.equal(
        masked.allowed_places(ground_floor, goal, rule="gap"), place_allowed(ground_floor, goal)
    )


# stack-pallet's shape: four cells 16 px (5 cm) apart, two layers
CELLS = [(64, 64), (64, 80), (80, 64), (80, 80)]
PALLET = [(*cell, layer) for layer in (0, 1) for cell in CELLS]


def test_layered_places_fill_the_lowest_layer_before_a_column_rises_on_it() -> None:
    goal, one_block = _stacked(PALLET), _stacked(PALLET[:1])
    ordered = place_allowed(one_block, goal, rule="ordered")[0]
    layered = place_allowed(one_block, goal, rule="layered")[0]
    assert ordered[CELLS[0]] and not any(ordered[cell] for cell in CELLS[1:])  # a column on the first
    assert not layered[CELLS[0]] and all(layered[cell] for cell in CELLS[1:])  # the other three cells
    assert (layered <= place_allowed(one_block, goal)[0]).all()
    ground_floor = _stacked(PALLET[:4])  # the first layer done: the second, on every cell
    assert all(place_allowed(ground_floor, goal, rule="layered")[0][cell] for cell in CELLS)
    building, columns = _stacked(BUILDING), _stacked(BUILDING[:2])  # the bridge still waits for its columns
    layered = place_allowed(columns, building, rule="layered")[0]
    assert layered[LEFT] and layered[RIGHT] and not layered[BRIDGE]
    assert place_allowed(_stacked(BUILDING[:4]), building, rule="layered")[0][BRIDGE]


def test_lowest_places_keep_where_a_block_lands_lowest() -> None:
    current = _stacked([(40, 40, 0), (40, 40, 1), (100, 100, 0)])
    allowed = torch.zeros(1, 160, 160, dtype=torch.bool)
    for cell in ((40, 40), (100, 100), (130, 30)):
        allowed[(0, *cell)] = True
    lowest = lowest_places(current, allowed)[0]
    assert lowest[130, 30] and not lowest[40, 40] and not lowest[100, 100]
    allowed[0, 130, 30] = False  # the table is gone: the one-block column is the lowest left
    lowest = lowest_places(current, allowed)[0]
    assert lowest[100, 100] and not lowest[40, 40]


def test_layered_places_skip_a_sliver_a_misplaced_block_left_and_centre_turned_cells() -> None:
    goal = _stacked([(80, 60, 0), (80, 76, 0), (80, 76, 1)])  # a step: one block, then two
    shifted = _stacked([(80, 62, 0), (80, 76, 0)])  # the first block 2 px off: a sliver of its cell open
    assert fitting_places(shifted, goal)[0][80, 76] and not fitting_places(shifted, goal)[0][80, 55]
    layered = place_allowed(shifted, goal, rule="layered")[0]
    assert layered[80, 76] and not layered[:, :70].any()  # onto the column, not onto the sliver
    turned = _turned_cells([(80.0, 80.0)])  # a cell turned by 45 degrees
    middles = place_allowed(to_rgbh(*draw_blocks([])), turned, rule="layered")[0]
    rows, cols = torch.nonzero(middles, as_tuple=True)
    assert middles[80, 80] and (rows - 80).abs().max() <= 1 and (cols - 80).abs().max() <= 1


def test_the_goal_seams_close_and_a_disc_maximum_matches_the_disc() -> None:
    goal = _stacked([(80, 64, 0), (80, 80, 0), (40, 40, 0), (40, 60, 0)])  # seams of 3 and 7 pixels
    closed = seams_closed(goal)
    assert torch.equal(closed[:, :3], goal[:, :3])
    assert closed[0, 3, 80, 72] == goal[0, 3, 80, 64]  # the 1 cm seam between neighbours is closed
    assert closed[0, 3, 40, 50] == goal[0, 3, 40, 50]  # a gap wider than the window stays open
    height = torch.randn(2, 40, 40, generator=torch.Generator().manual_seed(0))
    for diameter in (9, 13):
        pad = diameter // 2
        windows = F.unfold(F.pad(height[:, None], (pad,) * 4, value=-torch.inf), diameter)
        inside = _disc(diameter).flatten() > 0
        expected = windows[:, inside].max(dim=1).values.view(2, 40, 40)
        assert torch.equal(_disc_max(height, diameter), expected)


def test_disc_and_box_counts_and_the_seam_closing_match_plain_convolutions_and_pools() -> None:
    generator = torch.Generator().manual_seed(1)
    mask = torch.rand(3, 37, 41, generator=generator) > torch.tensor([0.2, 0.5, 0.9]).view(3, 1, 1)
    region = mask[:, None].float()
    for diameter in (5, 13):
        kernel = (_disc(diameter) > 0).float()
        expected = F.conv2d(region, kernel, padding=diameter // 2)[:, 0]
        assert torch.equal(_disc_count(mask, diameter).float(), expected)
    for size in (3, 25):
        expected = F.avg_pool2d(region, size, stride=1, padding=size // 2, divisor_override=1)[:, 0]
        assert torch.equal(_box_count(mask, size).float(), expected)
    image = torch.rand(2, 4, 30, 30, generator=generator)
    opened = F.max_pool2d(image[:, 3:4], SEAM_PX, stride=1, padding=SEAM_PX // 2)
    closed = -F.max_pool2d(-opened, SEAM_PX, stride=1, padding=SEAM_PX // 2)
    assert torch.equal(seams_closed(image)[:, 3:4], closed)


def test_layered_places_read_a_half_filled_goal_seam_as_the_blocks_top() -> None:
    goal = _stacked(PALLET)
    goal[0, 3, 71:74, 58:87] = goal[0, 3, 64, 64] * 0.6  # the fused map fills the seam part way
    layered = place_allowed(_stacked([]), goal, rule="layered")[0]
    assert all(layered[cell] for cell in CELLS)  # not only the seam, which one block does not finish
    assert not layered[72, 64:81].all()


def _columns(places: torch.Tensor) -> set[int]:
    return set(torch.nonzero(places[0])[:, 1].tolist())


def test_layered_places_fill_a_layer_from_its_ends_in_onto_the_goals_cells() -> None:
    base = [(80, 64, 0), (80, 80, 0), (80, 96, 0)]  # a row of three cells, 16 px (5 cm) apart
    pyramid = _stacked([*base, (80, 72, 1), (80, 88, 1), (80, 80, 2)])
    row = _stacked([*base, *((r, c, 1) for r, c, _ in base)])  # a flat-topped row two layers high
    first_layer = _stacked(base)
    first_layer[0, 3, 74:87, [71, 72, 73, 87, 88, 89]] = first_layer[0, 3, 80, 64] / 2  # part-filled seams
    assert _columns(place_allowed(first_layer, pyramid, rule="layered")) <= {71, 72, 73, 87, 88, 89}
    assert _columns(place_allowed(first_layer, row, rule="layered")) <= {63, 64, 65, 95, 96, 97}
    assert _columns(place_allowed(_stacked([]), row, rule="layered")) <= {63, 64, 65, 95, 96, 97}
    corners = place_allowed(_stacked([]), _stacked(PALLET), rule="layered")[0]
    rows, cols = torch.nonzero(corners, as_tuple=True)
    assert all(corners[cell] for cell in CELLS) and not corners[72, 72]  # not between the four cells
    assert ((rows - 72).abs() >= 7).all() and ((cols - 72).abs() >= 7).all()
    building = _stacked(BUILDING)  # the bridge is the only place once its columns stand
    assert place_allowed(_stacked(BUILDING[:4]), building, rule="layered")[0][BRIDGE]
    fill = torch.zeros(1, 160, 160, dtype=torch.bool)
    fill[0, 74:87, 58:103] = True  # a row's fill region; every place of it is a candidate
    ends = _columns(flush_places(fill, fill))
    assert ends and all(c < 67 or c > 93 for c in ends)  # the row's ends, not its middle


def test_cells_places_put_a_block_beside_a_finished_one_on_its_own_cell() -> None:
    base = [(80, 64, 0), (80, 80, 0), (80, 96, 0)]  # a row of three cells, 16 px (5 cm) apart
    for layers in (1, 2):  # put-block-base's row, and stack-rectangle's two layers
        goal = _stacked([(r, c, layer) for layer in range(layers) for r, c, _ in base])
        goal[0, 3, 74:87, 58:103] = goal[0, 3, 80, 64]  # the fused map barely shows the seams
        under = base if layers == 2 else []
        finished_end = _stacked([*under, (80, 96, layers - 1)])  # one end of the top layer done
        layered = _columns(place_allowed(finished_end, goal, rule="layered"))
        cells = _columns(place_allowed(finished_end, goal, rule="cells"))
        assert max(layered) == 78  # the middle cell's places 2 px or more off it, away from the finished end
        assert cells == {63, 64, 65, 79, 80, 81}  # the free end, and the middle on its own cell
        nearer = _stacked([*under, (80, 94, layers - 1)])  # that end 2 px nearer the middle: pushed along
        assert _columns(place_allowed(nearer, goal, rule="cells")) == {63, 64, 65, 77, 78, 79}
        fill = open_cells(finished_end, seams_closed(goal), place_allowed(finished_end, goal))[0]
        assert fill[80, 58:87].all() and not fill[77:84, 87:].any()  # the seam beside the finished end: out
        if layers == 2:  # the first layer's blocks stand under the goal's height: none is finished
            first = _stacked(base)
            fill = place_allowed(first, goal)
            assert torch.equal(open_cells(first, goal, fill), fill)
            blurred = goal.clone()  # the goal's edge blurred down to near the first layer's top: a thin rim
            rim = torch.zeros(160, 160, dtype=torch.bool)
            rim[74:87, 58:103] = True
            rim[76:85, 60:101] = False
            blurred[0, 3, rim] = 0.7 * first[0, 3, 80, 64] + 0.3 * goal[0, 3, 80, 64]
            fill = place_allowed(first, blurred, rule="gap")
            assert torch.equal(open_cells(first, blurred, fill), fill)  # a rim is no finished block


@pytest.mark.parametrize("rule", PLACE_RULES)
def test_every_place_rule_commutes_with_the_turns_and_mirrors(rule: str) -> None:
    goal = _stacked([(60, 64, 0), (60, 80, 0), (60, 64, 1), (60, 80, 1), (60, 80, 2), (100, 40, 0)])
    current = _stacked([(60, 64, 0), (60, 80, 0)])
    current[0, 3, 54:67, 71:74] = current[0, 3, 60, 64] / 2  # a part-filled seam
    allowed = place_allowed(current, goal, rule=rule)
    for turns in range(1, 4):
        turned = place_allowed(
            torch.rot90(current, turns, (2, 3)), torch.rot90(goal, turns, (2, 3)), rule=rule
        )
        assert torch.equal(turned, torch.rot90(allowed, turns, (1, 2)))
    assert torch.equal(place_allowed(current.flip(3), goal.flip(3), rule=rule), allowed.flip(2))


def _turned_cells(centres: list[tuple[float, float]], layer_height: float = 0.04) -> torch.Tensor:
    """An RGB-H image of 13-pixel columns turned by 45 degrees at ``centres`` (row, col), their tops at
    ``layer_height`` metres."""
    color, height = draw_blocks([])
    rows, cols = torch.meshgrid(torch.arange(160.0), torch.arange(160.0), indexing="ij")
    for r, c in centres:
        cell = ((rows - r) * 0.7071 - (cols - c) * 0.7071).abs().le(6.4)
        cell &= ((rows - r) * 0.7071 + (cols - c) * 0.7071).abs().le(6.4)
        height[cell] = layer_height
    return to_rgbh(color, height)


def test_the_middle_of_a_turned_row_is_found_between_its_placed_neighbours() -> None:
    step = 16 / 2**0.5  # cells 16 px (5 cm) apart along a row turned by 45 degrees
    row = [(80 - step, 80 - step), (80.0, 80.0), (80 + step, 80 + step)]
    near = 14.5 / 2**0.5  # the two ends placed 1.5 px (5 mm) nearer the middle than the goal has them
    goal = _turned_cells(row, layer_height=0.08)  # two layers, as stack-rectangle
    ends = _turned_cells([(80 - near, 80 - near), (80 + near, 80 + near)])
    layered = place_allowed(ends, goal, rule="layered")[0]
    rows, cols = torch.nonzero(layered, as_tuple=True)
    assert layered[80, 80] and (rows - 80).abs().max() <= 2 and (cols - 80).abs().max() <= 2


def test_a_footprint_holding_exactly_the_share_of_the_best_is_centred() -> None:
    allowed = torch.zeros(1, 40, 40, dtype=torch.bool)
    allowed[0, 10:14, 15:25] = True  # 4 x 10 pixels: a footprint over all of it holds 40
    among = torch.zeros_like(allowed)
    among[0, 12, 20] = among[0, 17, 20] = True  # the second's footprint holds 3 of the 4 rows: 30
    assert torch.equal(centred_places(allowed, 0.75, among), among)  # 30 is 0.75 of 40: kept
    assert centred_places(allowed, 0.76, among).sum() == 1
    assert torch.equal(centred_places(allowed, 0.6, among, disc=True), among)  # the disc: 24 of 40
    assert centred_places(allowed, 0.61, among, disc=True).sum() == 1
