"""The support check: which places rest on a height map, and how the search ranks the ones that do not."""

import numpy as np
import pytest
import torch
from test_search import COST, ToyGctn, ToyVf, _plan, toy_search

import tvf.planning.search as search_module
from tvf.planning.search import PlannerConfig, TreeSearch
from tvf.planning.support import FALL_PENALTY, FOOTPRINT_RADIUS, OFFSETS, rests

BLOCK = 0.04
HALF = 6  # pixels: half a 4 cm block (12.8 px), rounded down


def _scene(*blocks: tuple[int, int, float]) -> torch.Tensor:
    """A (1, 160, 160) height map of square 13 px blocks (row, col, top height)."""
    h = torch.zeros(1, 160, 160)
    for r, c, top in blocks:
        h[0, r - HALF : r + HALF + 1, c - HALF : c + HALF + 1] = top
    return h


def _rests(heights: torch.Tensor, pick: tuple[int, int], place: tuple[int, int]) -> bool:
    return bool(rests(heights, torch.tensor([pick]), torch.tensor([place]))[0])


def test_the_footprint_is_the_blocks_inscribed_disc():
    assert pytest.approx(6.4) == FOOTPRINT_RADIUS
    assert (OFFSETS.float().norm(dim=1) <= 6.4).all() and len(OFFSETS) == 129
    assert {tuple(o) for o in OFFSETS.tolist()} >= {(6, 0), (0, -6), (4, 4)}


def test_a_block_rests_on_the_table_on_a_tower_and_across_a_bridge():
    far = (140, 140)  # the picked block, away from every place
    scene = _scene((140, 140, BLOCK), (80, 60, BLOCK))
    assert _rests(scene, far, (40, 40))  # the table
    assert _rests(scene, far, (80, 60))  # on the tower's top
    assert _rests(scene, far, (80, 63))  # a quarter off: its centre is still over the tower
    bridge = _scene((140, 140, BLOCK), (80, 54, BLOCK), (80, 68, BLOCK))  # a 1 px gap under the middle
    assert _rests(bridge, far, (80, 61))
    assert _rests(scene, far, (2, 2))  # at the image's edge the table goes on


@pytest.mark.parametrize("offset", [6, 8, 10])
def test_a_block_over_a_towers_edge_does_not_rest(offset: int):
    scene = _scene((140, 140, BLOCK), (80, 60, BLOCK))
    assert not _rests(scene, (140, 140), (80, 60 + offset))
    assert not _rests(scene, (140, 140), (80 - offset, 60))


def test_the_picked_block_leaves_before_the_place_is_read():
    single = _scene((80, 60, BLOCK))
    assert not _rests(single, (140, 140), (80, 67))  # half over its edge: another block falls
    assert _rests(single, (80, 60), (80, 67))  # the block itself, moved half its width: onto the table
    stack = _scene((80, 60, 2 * BLOCK))  # two blocks: the lower one stays and holds a small shift
    assert _rests(stack, (80, 60), (80, 63)) and not _rests(stack, (80, 60), (80, 68))
    picks, places = torch.tensor([[80, 60], [140, 140]]), torch.tensor([[80, 67]] * 2)
    out = rests(torch.cat([single, single]), picks, places)
    assert out.tolist() == [True, False]


def test_bad_shapes_are_named():
    with pytest.raises(ValueError, match="expected"):
        rests(torch.zeros(160, 160), torch.zeros(1, 2), torch.zeros(1, 2))
    with pytest.raises(ValueError, match="expected"):
        rests(torch.zeros(2, 160, 160), torch.zeros(1, 2), torch.zeros(1, 2))


def _falls_at(place: tuple[int, int]):
    """A stand-in support check: the place ``place`` never rests, every other one does."""

    def check(heights, picks, places):
        return torch.as_tensor([tuple(p) != place for p in places.tolist()])

    return check


def test_the_search_ranks_a_path_through_a_falling_place_under_every_resting_one(monkeypatch):
    plain = _plan(toy_search(2, 1))
    assert plain.first.place.tolist() == [1, 1]  # the greedy trap looks best
    monkeypatch.setattr(search_module, "rests", _falls_at((1, 1)))
    config = PlannerConfig(k=2, depth=3, support_check=True)
    plan = _plan(TreeSearch(ToyGctn(), ToyVf(), config))
    under = {n.index for n in plan.nodes if n.parent < 0 and n.place.tolist() == [1, 1]}
    for node in plan.nodes:  # the subtree of the first place (1, 1): its own node and every one below it
        if node.parent in under:
            under.add(node.index)
    assert len(under) == 1 + 2 + 2  # states 3 and 4 have one move each
    for node in plan.nodes:
        penalty = FALL_PENALTY if node.index in under else 0.0
        assert node.score == pytest.approx(0.99 ** (node.depth - 1) * (1.0 - node.distance))
        assert node.distance >= penalty and (node.score < 0) == (node.index in under)
    assert plan.first.place.tolist() == [6, 6]
    shallow = _plan(TreeSearch(ToyGctn(), ToyVf(), PlannerConfig(k=2, depth=1, support_check=True)))
    assert shallow.first.place.tolist() == [6, 6]  # at depth 1 too: the falling place is not taken
    fell = next(n for n in shallow.nodes if n.place.tolist() == [1, 1])
    assert fell.distance == pytest.approx(COST[1] + FALL_PENALTY)


def test_where_every_place_falls_the_least_distant_is_taken(monkeypatch):
    monkeypatch.setattr(search_module, "rests", lambda h, picks, places: torch.zeros(len(places), dtype=bool))
    plan = _plan(TreeSearch(ToyGctn(), ToyVf(), PlannerConfig(k=2, depth=1, support_check=True)))
    assert plan.first.place.tolist() == [1, 1] and np.isfinite(plan.nodes[plan.best].score)
