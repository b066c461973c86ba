"""Tree search: a toy world whose best first action is known, batching, scores, the planner presets."""

import math
from types import SimpleNamespace

import pytest
import torch

from tvf.models.gctn import GCTN
from tvf.models.presets import get_preset
from tvf.models.vf import VisualForesight
from tvf.planning.search import PlannerConfig, TreeSearch, height_distance

SIZE, ROTATIONS = 8, 4
# Toy world: a state is an id kept in pixel (0, 0) of channel 0; its height channel is a constant whose
# distance to the (all-zero) goal is COST[id]. From each state two place pixels lead to two next states.
#   0 --(1,1)--> 1 (cost 0.10: looks best now)    --> 3 or 4 (cost 0.60: a dead end)
#   0 --(6,6)--> 2 (cost 0.30: looks worse now)   --> 5 (cost 0.00: the goal) or 6 (0.30)
MOVES = {0: {(1, 1): 1, (6, 6): 2}, 1: {(2, 2): 3, (5, 5): 4}, 2: {(2, 2): 5, (5, 5): 6}}
COST = {0: 0.5, 1: 0.10, 2: 0.30, 3: 0.60, 4: 0.60, 5: 0.0, 6: 0.30}


def toy_image(state: int) -> torch.Tensor:
    image = torch.zeros(4, SIZE, SIZE)
    image[0, 0, 0] = state
    image[3] = COST[state] * 4  # D = sum |h| / (H * W * 4) = COST
    return image


def state_of(image: torch.Tensor) -> int:
    return int(round(float(image[0, 0, 0])))


class ToyGctn:
    preset = SimpleNamespace(n_rotations=ROTATIONS)
    transport = SimpleNamespace(goal_features=lambda goal: goal)
    channel_bins = torch.arange(ROTATIONS)

    def __init__(self) -> None:
        self.calls = []

    def pick_logits(self, states, goal):
        logits = torch.zeros(states.shape[0], SIZE, SIZE)
        logits[:, 3, 4] = 1.0
        return logits

    def place_map(self, states, goal, picks, goal_features):
        self.calls.append(states.shape[0])
        logits = torch.full((states.shape[0], ROTATIONS, SIZE, SIZE), -50.0)
        for b in range(states.shape[0]):
            for r, c in MOVES.get(state_of(states[b]), {(2, 2): state_of(states[b])}):
                logits[b, (r + c) % ROTATIONS, r, c] = 0.0
        return logits


class ToyVf:
    def predict_rgbh(self, states, picks, places, yaws):
        out = []
        for s, p in zip(states, places, strict=True):
            moves = MOVES.get(state_of(s), {})
            out.append(toy_image(moves.get(tuple(p.tolist()), state_of(s))))
        return torch.stack(out)


def toy_search(k: int, depth: int, batched: bool = True):
    return TreeSearch(ToyGctn(), ToyVf(), PlannerConfig(k=k, depth=depth, batched=batched))


def _plan(search):
    goal = torch.zeros(1, 4, SIZE, SIZE)
    return search.search(toy_image(0)[None], goal, keep_images=True)


def test_depth_one_is_misled_and_depth_three_finds_the_right_first_action():
    shallow, deep = _plan(toy_search(2, 1)), _plan(toy_search(2, 3))
    assert shallow.first.place.tolist() == [1, 1]  # the greedy trap
    assert deep.first.place.tolist() == [6, 6]  # the path through state 2 reaches the goal
    assert [state_of(deep.images[n.index]) for n in deep.path][:2] == [2, 5]
    assert deep.nodes[deep.best].distance == pytest.approx(0.0)
    assert deep.nodes[deep.best].score == pytest.approx(0.99 * 1.0)  # found at depth 2: gamma^(2-1) (C - 0)


def test_tree_shape_and_one_model_call_per_level():
    search = toy_search(2, 3)
    plan = _plan(search)
    # states 3-6 offer a single place: a node with fewer proposals than K just has fewer children
    assert [sum(n.depth == d for n in plan.nodes) for d in (1, 2, 3)] == [2, 4, 4]
    assert search.gctn.calls == [1, 2, 4]
    assert plan.counts == {"gctn_calls": 3, "vf_calls": 3, "gctn_states": 7, "vf_states": 10}
    for node in plan.nodes:  # children of a node share its pick and point back to it
        if node.parent >= 0:
            assert plan.nodes[node.parent].depth == node.depth - 1


def test_node_by_node_search_gives_the_same_plan():
    a, b = _plan(toy_search(2, 3)), _plan(toy_search(2, 3, batched=False))
    assert [(n.place.tolist(), n.rotation, n.score) for n in a.nodes] == [
        (n.place.tolist(), n.rotation, n.score) for n in b.nodes
    ]
    assert b.counts["gctn_calls"] == 7 and b.counts["vf_calls"] == 10


@pytest.mark.parametrize("symmetry", [1, 4])
def test_real_models_batched_equals_node_by_node(symmetry: int):
    preset = get_preset("smoke").replace(symmetry=symmetry, pad_features=symmetry > 1)
    gctn, vf = GCTN(preset, seed=1).eval(), VisualForesight(preset, seed=2).eval()
    gen = torch.Generator().manual_seed(0)
    current, goal = torch.randn(1, 4, 160, 160, generator=gen), torch.randn(1, 4, 160, 160, generator=gen)
    plans = [
        TreeSearch(gctn, vf, PlannerConfig(k=2, depth=2, batched=b)).search(current, goal) for b in (1, 0)
    ]
    assert plans[0].best == plans[1].best
    for x, y in zip(plans[0].nodes, plans[1].nodes, strict=True):
        assert x.place.tolist() == y.place.tolist() and x.rotation == y.rotation
        assert x.score == pytest.approx(y.score, abs=1e-5)
        assert x.rotation in gctn.channel_bins.tolist()  # nodes hold bins of a full turn


def test_height_distance_uses_the_reference_normalisation():
    a, b = torch.zeros(1, 4, 160, 160), torch.zeros(1, 4, 160, 160)
    a[0, 3, :13, :13] = 4.4  # one block-sized patch 4.4 normalised units high
    assert height_distance(a, b).item() == pytest.approx(169 * 4.4 / (160 * 160 * 4))
    a[0, :3] = 7.0  # colour does not count
    assert height_distance(a, b).item() == pytest.approx(169 * 4.4 / (160 * 160 * 4))


def test_planner_config_is_validated():
    with pytest.raises(ValueError):
        PlannerConfig(k=0)


def test_nan_input_is_rejected():
    bad = toy_image(0)[None].clone()
    bad[0, 3, 0, 0] = math.nan
    with pytest.raises(ValueError, match="NaN"):
        toy_search(2, 1).search(bad, torch.zeros(1, 4, SIZE, SIZE))
