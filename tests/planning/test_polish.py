"""The executed action polished on its one-step image (PlannerConfig.place_search, turn_search)."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from tvf.errors import TvfError
from tvf.geometry import world_to_pixel
from tvf.models.images import heights_of, to_rgbh
from tvf.planning.rigid import RigidForesight
from tvf.planning.search import MAX_PLACE_SEARCH, MAX_TURN_SEARCH, Node, PlannerConfig, TreeSearch
from tvf.planning.support import rests
from tvf.policies import PolicySpec, make_policy, planner_of
from tvf.sim.factory import sim_env
from tvf.tasks import get_task
from tvf.viz.plan import plan_record, polished_caption

ROTATIONS = 36
FORESIGHT = RigidForesight()


def _scene(blocks) -> torch.Tensor:
    """A normalised RGB-H scene (1, 4, 160, 160) with 13 px blocks at (row, col), 4 cm tall."""
    color = np.full((1, 160, 160, 3), 200, np.float32)
    height = np.zeros((1, 160, 160), np.float32)
    for r, c in blocks:
        color[0, r - 6 : r + 7, c - 6 : c + 7] = (220, 30, 30)
        height[0, r - 6 : r + 7, c - 6 : c + 7] = 0.04
    return to_rgbh(color, height)


def _search(vf, **config) -> TreeSearch:
    gctn = SimpleNamespace(preset=SimpleNamespace(n_rotations=ROTATIONS))
    return TreeSearch(gctn, vf, PlannerConfig(**config))


def _node(pick, place, rotation) -> Node:
    return Node(0, -1, 1, np.array(pick), np.array(place), rotation, 0.5, 0.5)


def _goal(pick, place, rotation) -> torch.Tensor:
    """The scene after the exact action: what the polish should find."""
    yaw = torch.tensor([rotation * 2 * math.pi / ROTATIONS])
    return FORESIGHT.predict_rgbh(SCENE, torch.tensor([pick]), torch.tensor([place]), yaw)


SCENE = _scene([(40, 40), (40, 120)])


@pytest.mark.parametrize(
    ("place", "rotation"), [((103, 97), 2), ((97, 101), 34), ((100, 100), 0), ((104, 96), 1)]
)
def test_the_polish_finds_the_place_and_turn_the_goal_shows(place, rotation):
    goal = _goal((40, 40), place, rotation)
    search = _search(FORESIGHT, place_search=4, turn_search=2)
    polished = search.polish(_node((40, 40), (100, 100), 0), SCENE, goal)
    assert tuple(polished.place) == place and polished.rotation == rotation
    assert polished.distance == pytest.approx(0.0, abs=1e-7) and polished.score == pytest.approx(1.0)
    assert tuple(polished.pick) == (40, 40)  # the pick is never moved


def test_a_reach_of_zero_leaves_that_part_alone():
    goal = _goal((40, 40), (103, 97), 2)
    turn_only = _search(FORESIGHT, turn_search=2).polish(_node((40, 40), (100, 100), 0), SCENE, goal)
    assert tuple(turn_only.place) == (100, 100)
    place_only = _search(FORESIGHT, place_search=4).polish(_node((40, 40), (100, 100), 0), SCENE, goal)
    assert place_only.rotation == 0 and tuple(place_only.place) != (100, 100)


class BlindVf:
    """A foresight that sees no change: every action imagines the scene as it is."""

    def predict_rgbh(self, rgbh, picks, places, yaws):
        return rgbh.clone()


def test_the_unmoved_action_wins_ties():
    search = _search(BlindVf(), place_search=3, turn_search=2)
    polished = search.polish(_node((40, 40), (100, 100), 5), SCENE, _goal((40, 40), (100, 100), 0))
    assert tuple(polished.place) == (100, 100) and polished.rotation == 5


def test_the_candidates_stay_inside_the_image_and_within_reach_of_the_proposal():
    search = _search(FORESIGHT, place_search=3, turn_search=2)
    node = _node((40, 40), (0, 159), 35)
    places, rotations = search._around(node, node.place, 35, "place", 3, (160, 160))
    assert len(places) == 17 and (places >= 0).all() and (places < 160).all()
    assert tuple(places[0]) == (0, 159) and (rotations == 35).all()  # the action held first
    _, turns = search._around(node, node.place, 1, "turn", 2, (160, 160))
    assert list(turns) == [1, 35, 34, 0, 33, 1]  # the held turn, then the proposal's, wrapped
    held = np.array([3, 156])  # a later stage: the held place first, the square still the proposal's
    places, _ = search._around(node, held, 35, "place", 3, (160, 160))
    assert tuple(places[0]) == (3, 156) and np.abs(places[1:] - node.place).max() <= 3


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"place_search": -1}, "place_search must be 0 to"),
        ({"place_search": MAX_PLACE_SEARCH + 1}, "place_search must be 0 to"),
        ({"turn_search": MAX_TURN_SEARCH + 1}, "turn_search must be 0 to"),
    ],
)
def test_the_reaches_are_checked(changes, message):
    with pytest.raises(ValueError, match=message):
        PlannerConfig(**changes)
    with pytest.raises(TvfError, match=message + ".*fix the planner flags"):
        planner_of(PolicySpec("tvf-large", **changes))


def test_a_policy_executes_the_polished_action_and_the_paper_none():
    env = sim_env(get_task("put-t"))
    obs, info = env.reset(seed=3)
    plain = make_policy(PolicySpec("tvf-large-no-image-rules", foresight="rigid", depth=1), env)
    plain.act(obs, info["goal"])
    assert plain.last_plan.polished is None and plain.last_plan.chosen is plain.last_plan.first
    spec = PolicySpec("tvf-large-no-image-rules", foresight="rigid", depth=1, place_search=3, turn_search=2)
    policy = make_policy(spec, env)
    action = policy.act(obs, info["goal"])
    plan = policy.last_plan
    assert plan.polished is not None and plan.chosen is plan.polished
    assert tuple(plan.polished.pick) == tuple(plan.first.pick)
    assert np.abs(plan.polished.place - plan.first.place).max() <= 3
    assert tuple(world_to_pixel(action[1, :2])) == tuple(plan.polished.place)
    assert plan.polished.distance <= plan.first.distance + 1e-9  # never worse than the unmoved action
    extra = {k: plan.counts[k] - plain.last_plan.counts[k] for k in ("vf_calls", "vf_states", "gctn_calls")}
    assert extra == {"vf_calls": 3, "vf_states": 6 + 50 + 6, "gctn_calls": 0}  # three stages, 7 x 7 square
    record = plan_record(plan)  # `tvf viz plan`'s plan.json names the executed action
    assert record["polished"]["place"] == plan.polished.place.tolist() and "polished" not in plan_record(
        plain.last_plan
    )
    assert polished_caption(plain.last_plan) == "" and "polished by" in polished_caption(plan)


def test_a_simulated_foresight_refuses_the_polish():
    env = sim_env(get_task("put-t"))
    with pytest.raises(TvfError, match="--place-search and --turn-search polish"):
        make_policy(PolicySpec("tvf-large", foresight="simulator", place_search=2), env)


def test_with_the_support_check_the_polish_keeps_to_places_that_rest():
    """A goal that shows the block half off the one below it: without the check the rigid image matches
    it exactly; with it the polish stays where the block's centre is over its support."""
    scene = _scene([(40, 40), (100, 100)])
    overhang = FORESIGHT.predict_rgbh(
        scene, torch.tensor([[40, 40]]), torch.tensor([[100, 108]]), torch.tensor([0.0])
    )
    node = _node((40, 40), (100, 100), 0)
    free = _search(FORESIGHT, place_search=8).polish(node, scene, overhang)
    assert tuple(free.place) == (100, 108)
    checked = _search(FORESIGHT, place_search=8, support_check=True).polish(node, scene, overhang)
    assert 100 < checked.place[1] < 108 and checked.distance < 1.0  # nearer, and resting: no penalty
    pick, place = torch.tensor([[40, 40]]), torch.as_tensor(checked.place[None])
    assert bool(rests(heights_of(scene), pick, place)[0])
