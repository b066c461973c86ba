"""The search with the simulator as its foresight (tvf.planning.simulated) and the snapshots it rests on."""

import numpy as np
import pytest

from tvf.errors import TvfError
from tvf.models.images import to_rgbh
from tvf.planning.search import height_distance
from tvf.planning.simulated import SimulatedSearch
from tvf.policies import PolicySpec, SimulatedTvfPolicy, make_policy, needs_env, policy_for
from tvf.sim.factory import sim_env
from tvf.tasks import get_task


def _scene(env):
    """Everything a step can change: block poses, the episode's counters, the last observation."""
    positions, quaternions = env.world.block_poses()
    seen = env.observe()
    return np.asarray(positions), np.asarray(quaternions), env.steps, env.terminated, seen["height"]


def _assert_same_scene(a, b):
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


def test_a_snapshot_puts_the_scene_and_the_counters_back():
    env = sim_env(get_task("stack-stair"))
    env.reset(seed=1)
    before = _scene(env)
    snapshot = env.snapshot()
    env.step(env.oracle_action())
    assert env.steps == 1 and not np.array_equal(_scene(env)[0], before[0])
    env.restore(snapshot, keep=True)
    _assert_same_scene(_scene(env), before)
    env.step(env.oracle_action())
    env.restore(snapshot)  # restorable twice with keep, then freed
    _assert_same_scene(_scene(env), before)


def _policy(env, k, depth, method="tvf-small-paper"):
    policy = make_policy(PolicySpec(method, k=k, depth=depth, foresight="simulator"), env)
    assert isinstance(policy, SimulatedTvfPolicy)
    return policy


def test_the_search_scores_real_outcomes_and_leaves_the_episode_as_it_was():
    env = sim_env(get_task("stack-stair"))
    obs, info = env.reset(seed=3)
    before = _scene(env)
    policy = _policy(env, k=2, depth=2)
    plan, actions = policy.search.search(obs, info["goal"], keep_images=True)
    _assert_same_scene(_scene(env), before)
    roots = [n for n in plan.nodes if n.parent < 0]
    assert len(roots) == 2 and len(plan.nodes) == 2 + 4  # breadth-first: the roots, then their children
    assert [n.depth for n in plan.nodes] == [1, 1, 2, 2, 2, 2]
    assert [n.parent for n in plan.nodes[2:]] == [0, 0, 1, 1]
    assert plan.counts["sim_steps"] == 6 and plan.counts["gctn_calls"] == 3
    assert plan.images.shape == (6, 4, 160, 160)
    goal = to_rgbh(info["goal"]["color"], info["goal"]["height"])
    for node in roots:  # each root's distance is what executing its action really gives
        snapshot = env.snapshot()
        seen, *_ = env.step(actions[node.index])
        real = float(height_distance(to_rgbh(seen["color"], seen["height"]), goal)[0])
        assert node.distance == pytest.approx(real, abs=2e-4)
        assert node.score == pytest.approx(1 - node.distance)
        env.restore(snapshot)
    for node in plan.nodes[2:]:
        assert node.score == pytest.approx(0.99 * (1 - node.distance))
    best = max(plan.nodes, key=lambda n: n.score)
    assert plan.nodes[plan.best].score == best.score
    action = policy.act(obs, info["goal"])
    np.testing.assert_array_equal(action, actions[plan.path[0].index])
    _assert_same_scene(_scene(env), before)


def test_one_proposal_one_level_is_the_greedy_gctn():
    env = sim_env(get_task("put-t"))
    obs, info = env.reset(seed=5)
    greedy = make_policy(PolicySpec("gctn-paper")).act(obs, info["goal"])
    np.testing.assert_allclose(_policy(env, k=1, depth=1).act(obs, info["goal"]), greedy)


def test_a_finished_structure_is_not_searched_past():
    env = sim_env(get_task("stack-stair"))
    obs, info = env.reset(seed=1)
    for _ in range(get_task("stack-stair").horizon - 1):  # the expert leaves one block to place
        obs, *_ = env.step(env.oracle_action())
    plan, actions = _policy(env, k=2, depth=2).search.search(obs, info["goal"])
    finishes = []
    for node in [n for n in plan.nodes if n.parent < 0]:
        snapshot = env.snapshot()
        finishes.append(env.step(actions[node.index])[2])
        env.restore(snapshot)
        children = [n for n in plan.nodes if n.parent == node.index]
        assert len(children) == (0 if finishes[-1] else 2)
    assert any(finishes)  # the case under test happens here


def test_the_simulated_foresight_needs_its_episodes_simulator_and_a_search():
    assert needs_env(PolicySpec("tvf-large", foresight="simulator"))
    assert not needs_env(PolicySpec("tvf-large"))
    with pytest.raises(TvfError, match="executes the search's actions in the simulator"):
        make_policy(PolicySpec("tvf-large", foresight="simulator"))
    with pytest.raises(
        TvfError, match="unknown --foresight 'dream'; choose one of vf, simulator, simulator-"
    ):
        make_policy(PolicySpec("tvf-large", foresight="dream"))
    with pytest.raises(TvfError, match="gctn does not search; --foresight needs one of"):
        make_policy(PolicySpec("gctn", foresight="simulator"))
    env = sim_env(get_task("put-t"))
    first, second = (policy_for(PolicySpec("tvf-small", foresight="simulator"), env) for _ in range(2))
    assert first is not second  # bound to its episode's simulator, never cached across environments


def test_an_environment_without_snapshots_is_refused_in_one_line():
    env = sim_env(get_task("put-t"))
    proposer = make_policy(PolicySpec("tvf-small-paper")).search
    with pytest.raises(TvfError, match="needs an environment that can save and restore its scene"):
        SimulatedSearch(proposer, object())
    assert SimulatedSearch(proposer, env).config.k == 2


def test_propose_gives_the_proposals_of_a_searchs_root():
    env = sim_env(get_task("stack-rectangle"))
    obs, info = env.reset(seed=7)
    current, goal = (to_rgbh(x["color"], x["height"]) for x in (obs, info["goal"]))
    for method in ("tvf-large-paper", "tvf-large"):  # K-means over one pick; NMS over three picks
        search = make_policy(PolicySpec(method, depth=1)).search
        plan = search.search(current, goal)
        props, bins = search.propose(current, goal)
        roots = [n for n in plan.nodes if n.parent < 0]
        np.testing.assert_array_equal(props.places, [n.place for n in roots])
        np.testing.assert_array_equal(props.picks, [n.pick for n in roots])
        np.testing.assert_array_equal(bins, [n.rotation for n in roots])


def test_simulator_first_executes_the_first_actions_and_imagines_below_them():
    env = sim_env(get_task("stack-stair"))
    obs, info = env.reset(seed=3)
    before = _scene(env)
    spec = PolicySpec("tvf-small-paper", k=2, depth=2, foresight="simulator-first")
    policy = make_policy(spec, env)
    plan, actions = policy.search.search(obs, info["goal"], keep_images=True)
    _assert_same_scene(_scene(env), before)
    assert [n.depth for n in plan.nodes] == [1, 1, 2, 2, 2, 2]
    assert [n.parent for n in plan.nodes[2:]] == [0, 0, 1, 1]
    assert len(actions) == 2 and plan.counts["sim_steps"] == 2
    assert plan.counts["vf_calls"] == 1 and plan.counts["vf_states"] == 4
    assert plan.images.shape == (6, 4, 160, 160)
    # below each executed action: the VF search's own children of the real outcome, one level deeper
    vf_search = make_policy(PolicySpec("tvf-small-paper", k=2, depth=1)).search
    goal = to_rgbh(info["goal"]["color"], info["goal"]["height"])
    for root in plan.nodes[:2]:
        snapshot = env.snapshot()
        seen, *_ = env.step(actions[root.index])
        env.restore(snapshot)
        alone = vf_search.search(to_rgbh(seen["color"], seen["height"]), goal)
        below = [n for n in plan.nodes if n.parent == root.index]
        np.testing.assert_array_equal([n.place for n in below], [n.place for n in alone.nodes])
        assert [n.distance for n in below] == pytest.approx([n.distance for n in alone.nodes], abs=1e-6)
        assert [n.score for n in below] == pytest.approx([0.99 * n.score for n in alone.nodes], abs=1e-6)
    assert needs_env(spec)


def test_a_search_that_imagines_below_needs_a_vf():
    env = sim_env(get_task("put-t"))
    proposer = make_policy(PolicySpec("tvf-small-paper", depth=2)).search
    proposer.vf = None
    with pytest.raises(TvfError, match="imagines its deeper levels needs a VF"):
        SimulatedSearch(proposer, env, executed=1)
