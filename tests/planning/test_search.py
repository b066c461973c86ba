"""Tree search: a toy world whose best first action is known, batching, scores, the planner presets."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from tvf.models.gctn import GCTN
from tvf.models.images import HEIGHT_MEAN, HEIGHT_STD, heights_of, to_rgbh
from tvf.models.presets import get_preset
from tvf.models.vf import VisualForesight
from tvf.planning.search import Node, PlannerConfig, TreeSearch, best_node, height_distance

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

    def pick_pixels(self, states, picks):
        return picks

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


def test_root_k_widens_the_root_and_keeps_k_below():
    wide = TreeSearch(ToyGctn(), ToyVf(), PlannerConfig(k=1, root_k=2, depth=2))
    plan = _plan(wide)
    assert [sum(n.depth == d for n in plan.nodes) for d in (1, 2)] == [2, 2]  # 2 root actions, 1 child each
    assert {tuple(n.place.tolist()) for n in plan.nodes if n.depth == 1} == {(1, 1), (6, 6)}
    narrow = _plan(TreeSearch(ToyGctn(), ToyVf(), PlannerConfig(k=2, root_k=1, depth=2)))
    assert [sum(n.depth == d for n in narrow.nodes) for d in (1, 2)] == [1, 2]
    # the wide root looks past the greedy trap (1, 1) with one child per action and reaches the goal
    assert plan.first.place.tolist() == [6, 6] and plan.nodes[plan.best].distance == pytest.approx(0.0)


def test_root_alpha_lowers_the_threshold_of_the_first_actions_only():
    """A second place 0.5 % as likely as the best passes alpha 0.001 but not 0.01: with ``root_alpha`` the
    root has both, deeper nodes keep one child each (the tree stays as pruned as with 0.01)."""
    logits = torch.full((ROTATIONS, SIZE, SIZE), -50.0)
    logits[0, 1, 1], logits[0, 6, 6] = 0.0, math.log(0.005)

    def widths(**settings) -> list[int]:
        config = PlannerConfig(k=2, depth=2, proposals="nms", nms_radius=2.0, **settings)
        plan = _plan(TreeSearch(MapToyGctn(logits), ToyVf(), config))
        return [sum(n.depth == d for n in plan.nodes) for d in (1, 2)]

    assert widths() == [1, 1]  # the paper's alpha 0.01 everywhere
    assert widths(root_alpha=0.001) == [2, 2]
    assert widths(alpha=0.001) == [2, 4]
    cfg = PlannerConfig(alpha=0.02, root_alpha=0.001)
    assert [cfg.alpha_at(level) for level in (1, 2, 3)] == [0.001, 0.02, 0.02]
    assert PlannerConfig().alpha_at(1) == 0.01


def test_pick_branches_are_capped_by_each_level_k():
    cfg = PlannerConfig(k=2, root_k=6, pick_branches=3, depth=3)
    assert [cfg.k_at(level) for level in (1, 2, 3)] == [6, 2, 2]
    assert [cfg.pick_branches_at(level) for level in (1, 2, 3)] == [3, 2, 2]
    assert PlannerConfig(k=3).k_at(1) == 3 and PlannerConfig(k=3).widest == 3


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
    b[0, 3] = 1.5  # a raised goal: the distance is to it, not to the floor
    assert height_distance(b, b).item() == 0.0
    assert height_distance(a, b).item() == pytest.approx((169 * 2.9 + (25600 - 169) * 1.5) / (160 * 160 * 4))


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


# Goal world: the toy world, but the GCTN reads a goal id (channel 1, pixel (0, 0) of the goal): the pick
# column and the rotation channel of every place depend on it, so a state planned against another root's
# goal gives other nodes. Each call records its rows (states, goal rows) to show which rows shared a call.
# With ``turns`` the goal features are a symmetrised GCTN's stack (turns, B, C, H, W).
def goal_image(goal_id: int, target: int) -> torch.Tensor:
    image = toy_image(target)
    image[1, 0, 0] = goal_id
    return image


def _goal_ids(goal: torch.Tensor, rows: int) -> list[int]:
    return [int(x) for x in torch.broadcast_to(goal[:, 1, 0, 0], (rows,))]


class GoalToyGctn(ToyGctn):
    def __init__(self, turns: int = 0) -> None:
        super().__init__()
        self.turns = turns

    def goal_features(self, goal):
        self.calls.append(("goal", goal.shape[0]))
        return torch.stack([goal] * self.turns) if self.turns else goal

    def pick_logits(self, states, goal):
        self.calls.append(("pick", states.shape[0], goal.shape[0]))
        logits = torch.zeros(states.shape[0], SIZE, SIZE)
        for b, g in enumerate(_goal_ids(goal, states.shape[0])):
            logits[b, 3, g % SIZE] = 1.0
        return logits

    def place_maps(self, states, goal, picks, goal_features):
        assert goal_features.dim() == (5 if self.turns else 4)
        features = goal_features[-1] if self.turns else goal_features
        self.calls.append(("place", states.shape[0], features.shape[0]))
        logits = torch.full((states.shape[0], picks.shape[1], ROTATIONS, SIZE, SIZE), -50.0)
        for b, g in enumerate(_goal_ids(features, states.shape[0])):
            for r, c in MOVES.get(state_of(states[b]), {(2, 2): state_of(states[b])}):
                logits[b, :, (r + c + g) % ROTATIONS, r, c] = 0.0
        return logits


class CountingToyVf(ToyVf):
    def __init__(self) -> None:
        self.calls: list[int] = []

    def predict_rgbh(self, states, picks, places, yaws):
        self.calls.append(states.shape[0])
        return super().predict_rgbh(states, picks, places, yaws)


# Three roots: state 0 towards the goal state 5, state 2 towards state 6 and state 3 (one place only, so
# a single child per level) towards state 1; goal ids 1, 2, 3.
ROOTS = torch.stack([toy_image(0), toy_image(2), toy_image(3)])
GOALS = torch.stack([goal_image(1, 5), goal_image(2, 6), goal_image(3, 1)])


def _nodes(plan) -> list[tuple]:
    return [
        (n.parent, n.depth, n.pick.tolist(), n.place.tolist(), n.rotation, n.distance, n.score)
        for n in plan.nodes
    ]


def _goal_search(mix_roots, batched: bool = True, turns: int = 0) -> TreeSearch:
    config = PlannerConfig(k=2, depth=2, batched=batched)
    return TreeSearch(GoalToyGctn(turns), CountingToyVf(), config, mix_roots)


@pytest.mark.parametrize("turns", [0, 2])
@pytest.mark.parametrize(
    ("mix_roots", "batched"), [(False, True), (True, True), (None, True), (False, False)]
)
def test_each_root_is_planned_against_its_own_goal_as_a_single_search(mix_roots, batched: bool, turns: int):
    for n in (2, 3):
        plans = _goal_search(mix_roots, batched, turns).search_many(ROOTS[:n], GOALS[:n], keep_images=True)
        for i, plan in enumerate(plans):
            single = _goal_search(False, batched, turns)
            alone = single.search(ROOTS[i : i + 1], GOALS[i : i + 1], keep_images=True)
            assert _nodes(plan) == _nodes(alone)
            assert plan.best == alone.best and plan.counts == alone.counts
            assert torch.equal(plan.images, alone.images)
            assert torch.equal(plan.pick_logits, alone.pick_logits)
            assert torch.equal(plan.place_logits, alone.place_logits)
        assert [plan.first.pick.tolist() for plan in plans] == [[3, 1], [3, 2], [3, 3]][:n]  # own goals
        assert [plan.first.place.tolist() for plan in plans] == [[6, 6], [5, 5], [2, 2]][:n]
        assert [plan.nodes[plan.best].distance for plan in plans] == [0.0, 0.0, pytest.approx(0.5)][:n]
        assert [len(plan.nodes) for plan in plans] == [6, 4, 2][:n]


PER_ROOT_CALLS = [("goal", 1)] * 3 + [("pick", 1, 1), ("place", 1, 1)] * 3 + [
    ("pick", 2, 1), ("place", 2, 1), ("pick", 2, 1), ("place", 2, 1), ("pick", 1, 1), ("place", 1, 1)
]  # fmt: skip
MIXED_CALLS = [("goal", 3), ("pick", 3, 3), ("place", 3, 3), ("pick", 5, 5), ("place", 5, 5)]


@pytest.mark.parametrize("turns", [0, 2])
def test_rows_share_a_model_call_per_root_unless_mixed(turns: int):
    """Per root (the CPU default): each call holds one root's rows and its one goal image, the calls of
    a single search. Mixed: one call per level over every root's rows, each with its own goal."""
    for mix_roots in (False, None):  # None: the device rule, per root on the CPU
        search = _goal_search(mix_roots, turns=turns)
        search.search_many(ROOTS, GOALS)
        assert search.gctn.calls == PER_ROOT_CALLS and search.vf.calls == [2, 2, 1, 4, 2, 1]
    two = _goal_search(False, turns=turns)
    two.search_many(ROOTS[:2], GOALS[:2])
    assert two.gctn.calls[:2] == [("goal", 1), ("goal", 1)]
    mixed = _goal_search(True, turns=turns)
    mixed.search_many(ROOTS, GOALS)
    assert mixed.gctn.calls == MIXED_CALLS and mixed.vf.calls == [5, 7]
    one = _goal_search(False, turns=turns)
    one.search_many(ROOTS[:1], GOALS[:1])
    assert one.gctn.calls[0] == ("goal", 1)


def test_mix_roots_none_follows_the_device_rule(monkeypatch):
    import tvf.planning.search as search_module

    monkeypatch.setattr(search_module, "mixes_environments", lambda device: True)  # as on a GPU
    follows = _goal_search(None)
    follows.search_many(ROOTS, GOALS)
    assert follows.gctn.calls == MIXED_CALLS
    explicit = _goal_search(False)  # an explicit setting wins over the device rule
    explicit.search_many(ROOTS, GOALS)
    assert explicit.gctn.calls == PER_ROOT_CALLS


class MapToyGctn(ToyGctn):
    """The same place logits (R, H, W) at every state and pick, on a turn layout of ``n_rotations`` bins."""

    def __init__(self, logits: torch.Tensor, n_rotations: int = ROTATIONS) -> None:
        super().__init__()
        self.logits, self.preset = logits, SimpleNamespace(n_rotations=n_rotations)

    def place_maps(self, states, goal, picks, goal_features):
        return self.logits.expand(states.shape[0], picks.shape[1], *self.logits.shape).clone()


def _root_proposals(gctn, config: PlannerConfig):
    plan = TreeSearch(gctn, ToyVf(), config).search(toy_image(0)[None], torch.zeros(1, 4, SIZE, SIZE))
    return plan.root_proposals


def test_the_rotation_tolerance_is_measured_over_the_period_the_channels_cover():
    """Four channels of a 36-bin turn cover 40 degrees (10 per channel, a 9-fold symmetry's layout): with a
    tolerance of exactly 10 degrees both neighbours of the best channel are the same placement."""
    logits = torch.full((4, SIZE, SIZE), -50.0)
    for channel, value in ((1, 0.0), (2, -0.1), (0, -0.2), (3, -0.3)):
        logits[channel, 1, 1] = value
    config = PlannerConfig(k=4, depth=1, proposals="nms", nms_radius=2.0, nms_rotation=10.0)
    p = _root_proposals(MapToyGctn(logits, n_rotations=36), config)
    assert p.places.tolist() == [[1, 1], [1, 1]] and p.rotations.tolist() == [1, 3]


def _ring(n: int = 40) -> torch.Tensor:
    logits = torch.full((4, 48, 48), -100.0)
    for i in range(n):
        a = 2 * np.pi * i / n
        logits[i % 4, int(round(24 + 15 * np.sin(a))), int(round(24 + 15 * np.cos(a)))] = -0.001 * i / n
    return logits


@pytest.mark.parametrize(
    ("settings", "defaults_differ"),
    [
        (dict(k=2, alpha=0.02, top_n=30, seed=1), dict(top_n=100)),
        (dict(k=2, alpha=0.02, top_n=30, seed=3), dict(seed=0)),
        (dict(k=3, proposals="nms", alpha=0.02, nms_radius=40.0), dict(alpha=0.01)),
        (dict(k=3, proposals="nms", alpha=0.02, nms_radius=40.0), dict(nms_radius=BLOCK)),
    ],
)
def test_the_root_proposals_use_every_planner_setting(settings: dict, defaults_differ: dict):
    """The search's proposals are node_proposals with the config's settings; each case checks that the
    default of one setting would have given other proposals, so a setting dropped on the way is caught."""
    from tvf.planning.proposals import node_proposals

    logits = _ring()
    logits[2, 45, 2] = -4.2  # far from the ring, 1.5 % as likely as the best: between alpha 0.01 and 0.02
    gctn = MapToyGctn(logits)

    def expected(cfg: PlannerConfig):
        return node_proposals(logits[None], np.array([[3, 4]]), cfg.k, rule=cfg.proposals, alpha=cfg.alpha,
                              top_n=cfg.top_n, seed=cfg.seed, radius=cfg.nms_radius)  # fmt: skip

    config = PlannerConfig(depth=1, **settings)
    got, want = _root_proposals(gctn, config), expected(config)
    assert got.places.tolist() == want.places.tolist() and got.rotations.tolist() == want.rotations.tolist()
    assert got.picks.tolist() == [[3, 4]] * len(got)
    other = expected(PlannerConfig(depth=1, **{**settings, **defaults_differ}))
    assert other.places.tolist() != want.places.tolist()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (dict(k=0), "planner needs k >= 1 and depth >= 1, got k=0, depth=3"),
        (dict(depth=0), "planner needs k >= 1 and depth >= 1, got k=3, depth=0"),
        (dict(proposals="topk"), "unknown proposal rule 'topk'; choose one of kmeans, nms"),
        (
            dict(k=2, pick_branches=3),
            "pick_branches must be between 1 and k = 2 (the picks share the K proposals), got 3",
        ),
        (
            dict(pick_branches=0),
            "pick_branches must be between 1 and k = 3 (the picks share the K proposals), got 0",
        ),
        (dict(nms_radius=0.0), "nms_radius must be a positive number of pixels, got 0.0"),
        (dict(nms_radius=math.nan), "nms_radius must be a positive number of pixels, got nan"),
        (dict(nms_rotation=180.0), "nms_rotation must be None or degrees in [0, 180), got 180.0"),
        (dict(nms_rotation=-0.5), "nms_rotation must be None or degrees in [0, 180), got -0.5"),
        (dict(turns_depth=0), "turns_depth must be None or at least 1, got 0"),
        (dict(alpha=0.0), "alpha must be in (0, 1], got 0.0"),
        (dict(alpha=1.5), "alpha must be in (0, 1], got 1.5"),
        (dict(root_alpha=0.0), "root_alpha must be None or in (0, 1], got 0.0"),
        (dict(tie_band=-1e-4), "tie_band must be a score difference >= 0, got -0.0001"),
        (dict(tie_band=math.inf), "tie_band must be a score difference >= 0, got inf"),
        (dict(root_k=0), "root_k must be None or at least 1, got 0"),
        (dict(gamma=0.0), "gamma must be in (0, 1], got 0.0"),
        (dict(gamma=1.01), "gamma must be in (0, 1], got 1.01"),
        (
            dict(k=2, root_k=4, pick_branches=5),
            "pick_branches must be between 1 and root_k = 4 (the picks share the K proposals), got 5",
        ),
    ],
)
def test_config_errors_name_the_setting_and_the_value(changes: dict, message: str):
    with pytest.raises(ValueError) as error:
        PlannerConfig(**changes)
    assert str(error.value) == message


def test_config_accepts_the_edges_of_every_range():
    for edge in (
        dict(k=1, depth=1),
        dict(k=2, pick_branches=2),
        dict(nms_radius=0.5),
        dict(nms_rotation=0.0),
        dict(nms_rotation=179.9),
        dict(turns_depth=1),
        dict(alpha=1.0),
        dict(root_alpha=1.0),
        dict(tie_band=0.0),
        dict(k=2, root_k=4, pick_branches=4),
        dict(k=3, root_k=1),
        dict(gamma=1.0),
    ):
        config = PlannerConfig(**edge)
        assert all(getattr(config, key) == value for key, value in edge.items())


def tree(scores: dict[int, tuple[int, float]]) -> list[Node]:
    """Nodes in breadth-first order from {index: (parent, score)}."""
    zero = np.zeros(2, int)
    nodes = []
    for i, (parent, score) in sorted(scores.items()):
        depth = 1 if parent < 0 else nodes[parent].depth + 1
        nodes.append(Node(i, parent, depth, zero, zero, 0, 1.0 - score, score))
    return nodes


def test_the_tie_band_gives_near_ties_to_the_first_root_action_and_keeps_its_best_path():
    # roots 0, 1, 2 (proposal order); root 1's grandchild 7 is the best node by 0.0004
    nodes = tree({0: (-1, 0.950), 1: (-1, 0.940), 2: (-1, 0.930), 3: (0, 0.9600), 4: (0, 0.9550),
                  5: (1, 0.9580), 6: (2, 0.9000), 7: (5, 0.9604), 8: (3, 0.9590)})  # fmt: skip
    assert best_node(nodes) == best_node(nodes, 0.0) == 7  # the paper's rule: the best node
    assert best_node(nodes, 0.0001) == 7  # root 0's best (0.9600) is 0.0004 under: not a tie
    assert best_node(nodes, 0.0005) == 3  # a tie: root 0 comes first; its own best node
    assert best_node(nodes, 0.1) == 3  # every root ties: still root 0's best, not its first child
    equal = tree({0: (-1, 0.9), 1: (-1, 0.95), 2: (0, 0.95)})
    assert best_node(equal) == 1  # exact ties: the shallowest, as before


def test_the_first_step_band_keeps_depth_to_first_actions_the_one_step_foresight_cannot_tell_apart():
    # roots 0, 1, 2 score 0.950, 0.940, 0.930 themselves; root 2's grandchild 6 is the best node
    nodes = tree({0: (-1, 0.950), 1: (-1, 0.940), 2: (-1, 0.930), 3: (0, 0.9600), 4: (1, 0.9650),
                  5: (2, 0.9600), 6: (5, 0.9700)})  # fmt: skip
    assert best_node(nodes) == best_node(nodes, first_step_band=None) == 6  # the paper's: every root
    assert best_node(nodes, first_step_band=0.025) == 6  # root 2 is 0.020 under the best root: competes
    assert best_node(nodes, first_step_band=0.015) == 4  # root 2 dropped; root 1's subtree (0.965) wins
    assert best_node(nodes, first_step_band=0.005) == 3  # root 0 alone; its best node, not itself
    assert best_node(nodes, first_step_band=0.0) == 3
    # with a tie band too: the first competing root action within the band of the competing best
    assert (
        best_node(nodes, 0.006, first_step_band=0.015) == 3
        and best_node(nodes, 0.004, first_step_band=0.015) == 4
    )
    with pytest.raises(ValueError, match="first_step_band must be None or a score difference >= 0"):
        PlannerConfig(first_step_band=float("nan"))


def test_the_search_applies_its_tie_band():
    def first(band: float):
        search = TreeSearch(ToyGctn(), ToyVf(), PlannerConfig(k=2, depth=1, tie_band=band))
        plan = _plan(search)
        assert [n.place.tolist() for n in plan.nodes] == [[6, 6], [1, 1]]  # the proposal order
        return plan.first.place.tolist()

    # depth 1: the first proposal (6, 6) scores 0.70, the second (1, 1) 0.90
    assert first(0.0) == first(0.1) == [1, 1] and first(0.25) == [6, 6]


def _blocks(centres: list[tuple[int, int]]) -> torch.Tensor:
    """RGB-H (1, 4, 160, 160) of a grey table with 13 x 13 px, 4 cm red blocks at ``centres``."""
    from tvf.models.images import to_rgbh

    color, height = torch.full((160, 160, 3), 50.0), torch.zeros(160, 160)
    for r, c in centres:
        color[r - 6 : r + 7, c - 6 : c + 7] = torch.tensor([255.0, 87.0, 89.0])
        height[r - 6 : r + 7, c - 6 : c + 7] = 0.04
    return to_rgbh(color, height)


def test_a_goal_masked_gctn_picks_the_loose_block_and_proposes_places_the_goal_fills():
    from tvf.models.goal_mask import GoalMaskedGCTN, pick_allowed, place_allowed
    from tvf.models.symmetry import SymmetrizedGCTN

    preset = get_preset("smoke").replace(symmetry=4, pad_features=True)
    gctn = SymmetrizedGCTN(GoalMaskedGCTN(GCTN(preset, seed=1).eval()), 4)
    vf = VisualForesight(preset, seed=2).eval()
    current, goal = _blocks([(30, 30), (80, 80)]), _blocks([(80, 80), (80, 110), (120, 60)])
    config = PlannerConfig(k=3, depth=2, proposals="nms", pick_branches=2, turns_depth=1)
    plan = TreeSearch(gctn, vf, config).search(current, goal)
    picks, places = pick_allowed(current, goal)[0], place_allowed(current, goal)[0]
    roots = [n for n in plan.nodes if n.depth == 1]
    assert roots and all(picks[tuple(n.pick.tolist())] and places[tuple(n.place.tolist())] for n in roots)
    assert {tuple(n.pick.tolist()) for n in roots} <= {(r, c) for r in range(24, 37) for c in range(24, 37)}


def _heights(cells: dict[tuple[int, int], float]) -> torch.Tensor:
    """RGB-H (1, 4, 160, 160): 13 x 13 px columns of the given heights (m) at the given centres."""
    from tvf.models.images import to_rgbh

    color, height = torch.full((160, 160, 3), 50.0), torch.zeros(160, 160)
    for (r, c), h in cells.items():
        height[r - 6 : r + 7, c - 6 : c + 7] = h
    return to_rgbh(color, height)


class StillVf:
    """Imagines that nothing changes."""

    def predict_rgbh(self, states, picks, places, yaws):
        return states.clone()


def test_the_order_branch_proposes_where_one_block_finishes_the_goal_and_the_search_weighs_it():
    """The GCTN's places all lie on a two-block column of the goal (a block placed there now lands a layer
    too low); the order branch puts the one-block cell in place of the last proposal."""
    current = _heights({(30, 30): 0.04, (30, 60): 0.04})
    goal = _heights({(80, 80): 0.04, (80, 120): 0.08})
    logits = torch.full((ROTATIONS, 160, 160), -50.0)
    logits[0, 80, 120], logits[1, 80, 100] = 0.0, -0.5  # both on the tall cell's side, none at (80, 80)
    logits[2, 80, 80] = -20.0
    gctn = MapToyGctn(logits)

    def roots(order_branch: bool):
        config = PlannerConfig(k=2, depth=1, proposals="nms", order_branch=order_branch)
        plan = TreeSearch(gctn, StillVf(), config).search(current, goal)
        return [tuple(n.place.tolist()) for n in plan.nodes]

    assert roots(False) == [(80, 120), (80, 100)]
    assert roots(True) == [(80, 120), (80, 80)]  # the finishing cell, with the GCTN's best there


class CornerPicksGctn(MapToyGctn):
    """Picks ranked at two opposite corners of the block at (30, 30) (17 px apart), then one at (90, 100)."""

    def pick_logits(self, states, goal):
        logits = torch.full((states.shape[0], 160, 160), -50.0)
        logits[:, 24, 24], logits[:, 36, 36], logits[:, 94, 104] = 1.0, 0.9, 0.8
        return logits


def test_centred_picks_reach_the_search_and_two_picks_on_one_block_become_one():
    from tvf.models.pick_centre import CentredPickGCTN

    current, goal = _heights({(30, 30): 0.04, (90, 100): 0.04}), _heights({(80, 80): 0.04})
    logits = torch.full((ROTATIONS, 160, 160), -50.0)
    logits[0, 80, 80] = 0.0
    config = PlannerConfig(k=3, depth=1, proposals="nms", pick_branches=3)
    plain = TreeSearch(CornerPicksGctn(logits), StillVf(), config).search(current, goal)
    assert [tuple(n.pick.tolist()) for n in plain.nodes] == [(24, 24), (36, 36), (94, 104)]
    centred = TreeSearch(CentredPickGCTN(CornerPicksGctn(logits)), StillVf(), config).search(current, goal)
    assert [tuple(n.pick.tolist()) for n in centred.nodes] == [(30, 30), (90, 100)]


class HalfBlockVf:
    """Imagines every place as a block drawn 3 cm tall (a blurred 4 cm block)."""

    def predict_rgbh(self, states, picks, places, yaws):
        out = states.clone()
        for b, (r, c) in enumerate(places.tolist()):
            out[b, 3, r, c] = (0.03 - HEIGHT_MEAN) / HEIGHT_STD
        return out


@pytest.mark.parametrize("snap", [False, True])
def test_snap_heights_scores_and_expands_the_snapped_image(snap: bool):
    table = to_rgbh(torch.zeros(1, SIZE, SIZE, 3), torch.zeros(1, SIZE, SIZE))
    table[:, 0, 0, 0] = 0  # state 0 of the toy world: places (1, 1) and (6, 6)
    goal = table.clone()
    goal[:, 3, 1, 1] = (0.04 - HEIGHT_MEAN) / HEIGHT_STD
    search = TreeSearch(ToyGctn(), HalfBlockVf(), PlannerConfig(k=2, depth=1, snap_heights=snap))
    plan = search.search(table, goal, keep_images=True)
    assert plan.first.place.tolist() == [1, 1]
    drawn = heights_of(plan.images[plan.best][None])[0, 1, 1].item()
    assert drawn == pytest.approx(0.04 if snap else 0.03, abs=1e-6)
    one_centimetre = 0.01 / HEIGHT_STD / (SIZE * SIZE * 4)  # D of a 1 cm error at one pixel
    assert plan.first.distance == pytest.approx(0.0 if snap else one_centimetre, abs=1e-6)
