"""Tree search: a toy world whose best first action is known, batching, scores, the planner presets."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from tvf.models.gctn import GCTN
from tvf.models.presets import get_preset
from tvf.models.vf import VisualForesight
from tvf.planning.search import PlannerConfig, TreeSearch, height_distance

BLOCK = 13.0

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

    def __init__(self) -> None:
        self.calls = []

    def goal_features(self, goal):
        return goal

    def rotation_bins(self, channels):
        return torch.as_tensor(channels)

    def pick_logits(self, states, goal):
        logits = torch.zeros(states.shape[0], SIZE, SIZE)
        logits[:, 3, 4] = 1.0
        return logits

    def place_maps(self, states, goal, picks, goal_features):
        self.calls.append(states.shape[0])
        logits = torch.full((states.shape[0], picks.shape[1], ROTATIONS, SIZE, SIZE), -50.0)
        for b in range(states.shape[0]):
            for r, c in MOVES.get(state_of(states[b]), {(2, 2): state_of(states[b])}):
                logits[b, :, (r + c) % ROTATIONS, r, c] = 0.0
        return logits


class ToyVf:
    def predict_rgbh(self, states, picks, places, yaws):
        out = []
        for s, p in zip(states, places, strict=True):
            moves = MOVES.get(state_of(s), {})
            out.append(toy_image(moves.get(tuple(p.tolist()), state_of(s))))
        return torch.stack(out)


# Pick world: from state 0 two blocks can be picked. The attention prefers block A (pick (1, 6)), whose
# only place leads to state 1 (cost 0.10); block B (pick (6, 1)), picked second, leads to the goal (5).
PICK_MOVES = {0: {((1, 6), (2, 2)): 1, ((6, 1), (5, 5)): 5}}
PICK_SCORES = {(1, 6): 1.0, (6, 1): 0.5}


class PickToyGctn(ToyGctn):
    def pick_logits(self, states, goal):
        logits = torch.full((states.shape[0], SIZE, SIZE), -50.0)
        for (r, c), value in PICK_SCORES.items():
            logits[:, r, c] = value
        return logits

    def place_maps(self, states, goal, picks, goal_features):
        self.calls.append((states.shape[0], picks.shape[1]))
        logits = torch.full((states.shape[0], picks.shape[1], ROTATIONS, SIZE, SIZE), -50.0)
        for b in range(states.shape[0]):
            moves = PICK_MOVES.get(state_of(states[b]), {})
            for j, pick in enumerate(picks[b].tolist()):
                targets = [place for p, place in moves if list(p) == pick] or [(0, 0)]
                for r, c in targets:
                    logits[b, j, (r + c) % ROTATIONS, r, c] = 0.0
        return logits


class PickToyVf:
    def predict_rgbh(self, states, picks, places, yaws):
        out = []
        for s, pick, place in zip(states, picks, places, strict=True):
            moves = PICK_MOVES.get(state_of(s), {})
            out.append(toy_image(moves.get((tuple(pick.tolist()), tuple(place.tolist())), state_of(s))))
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
    assert search.gctn.calls == [1, 2, 4]  # one GCTN call per level
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


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (dict(proposals="topk"), "unknown proposal rule 'topk'"),
        (dict(k=2, pick_branches=3), "pick_branches must be between 1 and k = 2"),
        (dict(pick_branches=0), "pick_branches must be between 1"),
        (dict(nms_radius=0.0), "nms_radius must be a positive"),
        (dict(nms_radius=math.inf), "nms_radius must be a positive"),
        (dict(nms_rotation=-5.0), "nms_rotation must be None or degrees"),
        (dict(alpha=0.0), "alpha must be in"),
    ],
)
def test_config_rejects_bad_proposal_settings(changes: dict, message: str):
    with pytest.raises(ValueError, match=message):
        PlannerConfig(**changes)


def test_nan_input_is_rejected():
    bad = toy_image(0)[None].clone()
    bad[0, 3, 0, 0] = math.nan
    with pytest.raises(ValueError, match="NaN"):
        toy_search(2, 1).search(bad, torch.zeros(1, 4, SIZE, SIZE))


def _pick_plan(pick_branches: int, k: int = 2, batched: bool = True):
    cfg = PlannerConfig(k=k, depth=1, pick_branches=pick_branches, nms_radius=2.0, batched=batched)
    search = TreeSearch(PickToyGctn(), PickToyVf(), cfg)
    return search, _plan(search)


def test_pick_branching_finds_the_block_the_attention_ranks_second():
    _, one = _pick_plan(1)
    assert len(one.nodes) == 1 and one.first.pick.tolist() == [1, 6]  # one pick, one place: state 1
    search, two = _pick_plan(2)
    assert [n.pick.tolist() for n in two.nodes] == [[1, 6], [6, 1]]  # the greedy action stays first
    assert [n.place.tolist() for n in two.nodes] == [[2, 2], [5, 5]]
    assert two.first.pick.tolist() == [6, 1] and two.nodes[two.best].distance == pytest.approx(0.0)
    assert two.root_proposals.picks.tolist() == [[1, 6], [6, 1]]
    assert search.gctn.calls == [(1, 2)]  # both picks' place maps in one GCTN call
    _, unbatched = _pick_plan(2, batched=False)
    assert [(n.pick.tolist(), n.place.tolist(), n.score) for n in unbatched.nodes] == [
        (n.pick.tolist(), n.place.tolist(), n.score) for n in two.nodes
    ]


@pytest.mark.parametrize("symmetry", [1, 4])
def test_real_models_pick_branching_batched_equals_node_by_node(symmetry: int):
    preset = get_preset("smoke").replace(symmetry=symmetry, pad_features=symmetry > 1)
    gctn, vf = GCTN(preset, seed=1).eval(), VisualForesight(preset, seed=2).eval()
    gen = torch.Generator().manual_seed(0)
    current, goal = torch.randn(1, 4, 160, 160, generator=gen), torch.randn(1, 4, 160, 160, generator=gen)
    configs = [
        PlannerConfig(k=3, depth=2, proposals="nms", pick_branches=2, alpha=1e-3, batched=b) for b in (1, 0)
    ]
    plans = [TreeSearch(gctn, vf, cfg).search(current, goal) for cfg in configs]
    assert plans[0].best == plans[1].best
    for x, y in zip(plans[0].nodes, plans[1].nodes, strict=True):
        assert x.pick.tolist() == y.pick.tolist() and x.place.tolist() == y.place.tolist()
        assert x.rotation == y.rotation and x.score == pytest.approx(y.score, abs=1e-5)
    root = plans[0].root_proposals
    picks = {tuple(p) for p in root.picks.tolist()}
    assert len(root) == 3 and len(picks) == 2  # the best place at 2 picks + one more at the best pick
    a, b = (np.array(p) for p in picks)
    assert np.hypot(*(a - b)) >= BLOCK  # distinct blocks
    best_pick = gctn.pick_logits(current, goal)[0].argmax()
    assert root.picks[0].tolist() == [int(best_pick) // 160, int(best_pick) % 160]
    at_best = root.places[(root.picks == root.picks[0]).all(axis=1)]
    assert np.hypot(*(at_best[0] - at_best[1])) >= BLOCK  # NMS places at the best pick


def test_nms_with_one_pick_and_k1_is_the_gctn_greedy_action():
    preset = get_preset("smoke")
    gctn, vf = GCTN(preset, seed=1).eval(), VisualForesight(preset, seed=2).eval()
    gen = torch.Generator().manual_seed(3)
    current, goal = torch.randn(1, 4, 160, 160, generator=gen), torch.randn(1, 4, 160, 160, generator=gen)
    pick, place, rot, _ = gctn.act(current, goal)
    for rule in ("kmeans", "nms"):
        plan = TreeSearch(gctn, vf, PlannerConfig(k=1, depth=1, proposals=rule)).search(current, goal)
        node = plan.first
        assert (node.pick.tolist(), node.place.tolist(), node.rotation) == (
            pick[0].tolist(),
            place[0].tolist(),
            int(rot[0]),
        )


# Turn world: every state offers two places whose best rotation channels turn the block by +30 and -30
# degrees (36 bins). The VF must imagine exactly the turn the robot will execute for that node.
TURN_ROTATIONS = 36
TURNS = {(1, 1): 3, (6, 6): 33}  # place pixel -> rotation bin: +30 and -30 degrees


class TurnGctn(ToyGctn):
    preset = SimpleNamespace(n_rotations=TURN_ROTATIONS)

    def place_maps(self, states, goal, picks, goal_features):
        logits = torch.full((states.shape[0], picks.shape[1], TURN_ROTATIONS, SIZE, SIZE), -50.0)
        for (r, c), rot in TURNS.items():
            logits[:, :, rot, r, c] = 0.0
        return logits


class RecordingVf:
    def __init__(self) -> None:
        self.yaws: list[float] = []

    def predict_rgbh(self, states, picks, places, yaws):
        self.yaws += yaws.tolist()
        return states.clone()


def test_the_vf_imagines_the_turn_the_robot_executes():
    from tvf.geometry import wrap_angle
    from tvf.planning.actions import bin_action

    vf = RecordingVf()
    search = TreeSearch(TurnGctn(), vf, PlannerConfig(k=2, depth=2, proposals="nms", nms_radius=2.0))
    plan = search.search(toy_image(0)[None], torch.zeros(1, 4, SIZE, SIZE))
    assert len(vf.yaws) == len(plan.nodes) == 6
    height = np.zeros((SIZE, SIZE), np.float32)
    for node, imagined in zip(plan.nodes, vf.yaws, strict=True):
        assert node.rotation == TURNS[tuple(node.place.tolist())]
        executed = bin_action(node.pick, node.place, node.rotation, TURN_ROTATIONS, height)[1, 3]
        assert float(wrap_angle(imagined - executed)) == pytest.approx(0.0, abs=1e-6)
    assert sorted({round(math.degrees(float(wrap_angle(y)))) for y in vf.yaws}) == [-30, 30]


def test_turns_depth_symmetrises_the_root_only_and_the_plain_gctn_proposes_below():
    from tvf.models.symmetry import SymmetrizedGCTN

    preset = get_preset("smoke").replace(symmetry=4, pad_features=True)
    plain, vf = GCTN(preset, seed=1).eval(), VisualForesight(preset, seed=2).eval()
    calls = {"plain": 0, "sym": 0}

    class Counted(SymmetrizedGCTN):
        def pick_logits(self, current, goal):
            calls["sym"] += 1
            return super().pick_logits(current, goal)

    original = plain.pick_logits

    def counted_plain(current, goal):
        calls["plain"] += 1
        return original(current, goal)

    sym = Counted(plain, 4)
    gen = torch.Generator().manual_seed(0)
    current, goal = torch.randn(1, 4, 160, 160, generator=gen), torch.randn(1, 4, 160, 160, generator=gen)
    every = TreeSearch(sym, vf, PlannerConfig(k=2, depth=2)).search(current, goal)
    plain.pick_logits = counted_plain
    calls.update(plain=0, sym=0)
    root = TreeSearch(sym, vf, PlannerConfig(k=2, depth=2, turns_depth=1)).search(current, goal)
    assert calls == {"sym": 1, "plain": 4 + 1}  # the root once (4 turns inside), then one plain level
    ones = [(n.pick.tolist(), n.place.tolist(), n.rotation) for n in every.nodes if n.depth == 1]
    assert ones == [(n.pick.tolist(), n.place.tolist(), n.rotation) for n in root.nodes if n.depth == 1]
    with pytest.raises(ValueError, match="turns_depth must be None or at least 1"):
        PlannerConfig(turns_depth=0)
