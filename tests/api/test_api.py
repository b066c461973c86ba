"""The Python API: a planner from plain arrays, its decisions in the robot base frame, its errors."""

from __future__ import annotations

import re
from pathlib import Path

import gymnasium
import numpy as np
import pytest
import torch

import tvf
import tvf.envs  # noqa: F401  (registers the environments)
from tvf.errors import TvfError
from tvf.geometry import WORKSPACE, pixel_to_world
from tvf.models.goal_mask import mask_of
from tvf.policies import PolicySpec, make_policy


@pytest.fixture(scope="module")
def scene():
    env = gymnasium.make("tvf/StackTower-v0")
    obs, _ = env.reset(seed=3)
    yield env, obs
    env.close()


def test_the_gctn_builds_a_tower_from_arrays_alone(scene):
    env, obs = scene
    planner = tvf.load_planner("gctn")
    for _ in range(3):  # the shipped GCTN solves this scene in three steps (tests/policies)
        goal = obs["desired_goal"]
        decision = planner.next_action(obs["color"], obs["height"], goal["color"], goal["height"])
        np.testing.assert_allclose(pixel_to_world(np.array(decision.pick_pixel)), decision.pick[:2])
        np.testing.assert_allclose(pixel_to_world(np.array(decision.place_pixel)), decision.place[:2])
        assert decision.plan is None and decision.as_array().shape == (2, 4)
        obs, _, terminated, _, _ = env.step(decision.as_array())
    assert terminated


def test_a_tvf_decision_is_the_policys_and_keeps_its_plan(scene):
    _, obs = scene
    goal = obs["desired_goal"]
    planner = tvf.load_planner("tvf-small", k=2)
    decision = planner.next_action(obs["color"], obs["height"], goal["color"], goal["height"])
    policy = make_policy(PolicySpec("tvf-small", k=2))
    np.testing.assert_array_equal(decision.as_array(), policy.act(obs, goal))
    assert decision.plan is not None and decision.plan.counts["vf_calls"] >= 1
    assert repr(planner) == "Planner('tvf-small')"
    banded = tvf.load_planner("tvf-small", k=2, tie_band=0.5)  # every root action ties: the first one wins
    first = banded.next_action(obs["color"], obs["height"], goal["color"], goal["height"])
    assert first.plan.first.index == 0 and banded._policy.search.config.tie_band == 0.5


def test_every_planner_option_of_the_cli_reaches_the_search():
    options = dict(k=2, depth=2, proposals="nms", pick_branches=2, turns_depth=1, alpha=0.05, nms_radius=9.0,
                   tie_band=0.01, root_alpha=0.002, first_step_band=0.004)  # fmt: skip
    config = tvf.load_planner("tvf-large", **options)._policy.search.config
    assert {name: getattr(config, name) for name in options} == options
    ordered = tvf.load_planner("tvf-large", mask_places="ordered", centred_share=0.8)._policy.search.gctn
    assert mask_of(ordered).places == "ordered" and mask_of(ordered).share == 0.8
    centring = tvf.load_planner("gctn", centre_picks=True, turns=1)._policy.model
    assert type(centring).__name__ == "CentredPickGCTN"
    paper = tvf.load_planner("tvf-large-paper")._policy.search  # the paper's rules, by name
    assert (paper.config.proposals, paper.config.pick_branches, paper.config.tie_band) == ("kmeans", 1, 0.0)
    assert type(paper.gctn).__name__ == "GCTN"  # no turns averaged, nothing read from the height maps
    bare = tvf.load_planner("tvf-large-no-image-rules")._policy.search  # our search, no image rules
    assert bare.config == tvf.load_planner("tvf-large")._policy.search.config
    assert type(bare.gctn).__name__ == "SymmetrizedGCTN" and mask_of(bare.gctn) is None


def test_a_planner_can_foresee_without_a_network(scene):
    _, obs = scene
    goal = obs["desired_goal"]
    planner = tvf.load_planner("tvf-large-no-image-rules", foresight="rigid", support_check=True)
    search = planner._policy.search
    assert type(search.vf).__name__ == "RigidForesight" and search.config.support_check
    decision = planner.next_action(obs["color"], obs["height"], goal["color"], goal["height"])
    assert decision.as_array().shape == (2, 4) and decision.plan.counts["vf_states"] >= 3
    with pytest.raises(TvfError, match="only tvf eval and tvf ablate run it"):
        tvf.load_planner("tvf-large", foresight="simulator")
    with pytest.raises(TvfError, match="unknown --foresight 'dream'"):
        tvf.load_planner("tvf-large", foresight="dream")


def test_bad_arrays_and_arguments_are_one_line_errors(scene):
    _, obs = scene
    planner = tvf.load_planner("gctn")
    color, height = obs["color"], obs["height"]
    bad = {
        "color must be a uint8 array of shape (160, 160, 3)": (color.astype(np.uint16), height),
        "must be a float array of shape (160, 160)": (color, height[:80]),
        "holds NaN": (color, np.where(height > 0.01, np.nan, height).astype(np.float32)),
        "metres above the table, not mm": (color, height * 1000),
    }
    for match, (c, h) in bad.items():
        with pytest.raises(TvfError, match=re.escape(match)):
            planner.next_action(c, h, color, height)
    with pytest.raises(TvfError, match="goal_color must be"):
        planner.next_action(color, height, color[..., :2], height)
    for kwargs, match in (
        (dict(method="oracle"), "unknown planner 'oracle'"),
        (dict(method="tvf-large", beam=3), "unknown planner option 'beam'"),
        (dict(method="gctn", k=2), "gctn does not search"),
        (dict(method="gctn", tie_band=0.001), "gctn does not search"),
        (dict(method="tvf-large", tie_band=-1.0), "tie_band must be a score difference >= 0.*--tie-band"),
        (dict(method="tvf-large", gctn="/nowhere/run"), "nowhere"),
    ):
        with pytest.raises(TvfError, match=match):
            tvf.load_planner(**kwargs)
    assert WORKSPACE.shape == (160, 160)


def test_the_readme_example_runs_as_written(capsys):
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    code = readme.split("## Python API", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)
    decision = namespace["decision"]
    assert isinstance(decision, tvf.Decision) and decision.plan is not None
    x, y = decision.place[:2]
    assert WORKSPACE.x_min < x < WORKSPACE.x_max and WORKSPACE.y_min < y < WORKSPACE.y_max
    assert capsys.readouterr().out.count("[") == 2  # the printed pick and place poses
    namespace["env"].close()


def test_a_policy_with_nothing_to_do_is_a_one_line_error(scene):
    _, obs = scene
    planner = tvf.load_planner("gctn")
    planner._policy.act = lambda obs, goal: None  # the Policy contract allows None
    goal = obs["desired_goal"]
    with pytest.raises(TvfError, match="found no action"):
        planner.next_action(obs["color"], obs["height"], goal["color"], goal["height"])


def _decisions_before_and_after(planner, scene, transform):
    """The planner's decision on the scene, and on the scene with ``transform`` applied to every image."""
    _, obs = scene
    goal = obs["desired_goal"]
    arrays = (obs["color"], obs["height"], goal["color"], goal["height"])
    decision = planner.next_action(*arrays)
    moved = planner.next_action(*(np.ascontiguousarray(transform(a)) for a in arrays))
    return decision, moved


def test_a_symmetrised_gctn_turns_its_decision_with_the_scene(scene):
    from tvf.geometry import quarter_turn_pixels

    planner = tvf.load_planner("gctn", turns=4)
    decision, turned = _decisions_before_and_after(planner, scene, np.rot90)
    for name in ("pick_pixel", "place_pixel"):
        expected = quarter_turn_pixels(np.array(getattr(decision, name)), 1, 160)
        assert tuple(getattr(turned, name)) == tuple(expected.tolist())
    assert turned.rotation_bin == decision.rotation_bin  # the object's turn does not change
    with pytest.raises(TvfError, match="--turns must be 1, 2, 4 .* or 8"):
        tvf.load_planner("gctn", turns=3)


def test_the_eight_symmetries_mirror_the_decision_with_the_scene(scene):
    from tvf.geometry import mirror_pixels

    planner = tvf.load_planner("gctn", turns=8)
    decision, mirrored = _decisions_before_and_after(planner, scene, lambda a: np.flip(a, axis=1))
    for name in ("pick_pixel", "place_pixel"):
        expected = mirror_pixels(np.array(getattr(decision, name)), 160)
        assert tuple(getattr(mirrored, name)) == tuple(expected.tolist())
    n = planner.n_rotations
    assert mirrored.rotation_bin == (n - decision.rotation_bin) % n  # a mirror turns yaw into -yaw


def test_a_goal_masked_planner_picks_a_block_the_goal_does_not_have_there(scene):
    from tvf.models.goal_mask import GoalMaskedGCTN, pick_allowed, place_allowed
    from tvf.policies.learned import observation_tensor

    _, obs = scene
    goal = obs["desired_goal"]
    planner = tvf.load_planner("gctn", goal_mask=True, centre_picks=False)  # the GCTN's own pick pixel
    assert isinstance(planner._policy.model.gctn, GoalMaskedGCTN)  # inside the method's four turns
    decision = planner.next_action(obs["color"], obs["height"], goal["color"], goal["height"])
    current, target = (observation_tensor(o, torch.device("cpu")) for o in (obs, goal))
    assert pick_allowed(current, target)[0][tuple(decision.pick_pixel)]
    assert place_allowed(current, target)[0][tuple(decision.place_pixel)]


def test_a_refined_planner_turns_the_block_to_the_goals_yaw(scene):
    from tvf.geometry import wrap_symmetric
    from tvf.planning.yaw import face_yaw, structure_yaw
    from tvf.tasks import BLOCK_SYMMETRY

    _, obs = scene
    goal = obs["desired_goal"]
    plain = tvf.load_planner("gctn").next_action(obs["color"], obs["height"], goal["color"], goal["height"])
    refined = tvf.load_planner("gctn", refine_yaw=True).next_action(
        obs["color"], obs["height"], goal["color"], goal["height"]
    )
    assert (refined.pick_pixel, refined.place_pixel) == (plain.pick_pixel, plain.place_pixel)
    block, _ = face_yaw(obs["height"], np.array(refined.pick_pixel))
    target, _ = structure_yaw(goal["height"], np.array(refined.place_pixel))
    needed = target - block  # the turn that leaves the block at the goal's yaw
    assert abs(wrap_symmetric(refined.place[3] - needed, BLOCK_SYMMETRY)) < 1e-6
