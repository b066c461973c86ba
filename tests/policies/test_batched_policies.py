"""Batched decisions: N (observation, goal) pairs in one call give the actions of N single calls."""

import numpy as np
import pytest

from tvf.models.gctn import GCTN
from tvf.models.presets import get_preset
from tvf.models.symmetry import symmetrized
from tvf.models.vf import VisualForesight
from tvf.planning.search import PlannerConfig
from tvf.policies import GctnPolicy, PolicySpec, TvfPolicy, act_all, make_policy
from tvf.sim.factory import SimEnvFactory
from tvf.tasks import get_task


def _observations(n: int, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    return [{"color": rng.integers(0, 256, (160, 160, 3), dtype=np.uint8),
             "height": rng.uniform(0, 0.1, (160, 160)).astype(np.float32)} for _ in range(n)]  # fmt: skip


@pytest.mark.parametrize("mix", [False, True])
@pytest.mark.parametrize("turns", [1, 4])
def test_gctn_batched_acts_equal_single_acts(mix, turns):
    preset = get_preset("smoke").replace(symmetry=4)
    policy = GctnPolicy(symmetrized(GCTN(preset, seed=5), turns))
    policy.mix = mix
    obs, goals = _observations(3), _observations(3, seed=1)
    batched = policy.act_batch(obs, goals)
    single = [policy.act(o, g) for o, g in zip(obs, goals, strict=True)]
    assert all(np.array_equal(a, b) for a, b in zip(batched, single, strict=True))
    assert len({a.tobytes() for a in single}) > 1


def test_tvf_batched_acts_equal_single_acts_and_keep_the_last_plan():
    preset = get_preset("smoke").replace(symmetry=4)
    policy = TvfPolicy(GCTN(preset, seed=5), VisualForesight(preset, seed=6), PlannerConfig(k=2, depth=2))
    obs, goals = _observations(3), _observations(3, seed=1)
    batched = policy.act_batch(obs, goals)
    last = policy.last_plan
    single = [policy.act(o, g) for o, g in zip(obs, goals, strict=True)]
    assert all(np.array_equal(a, b) for a, b in zip(batched, single, strict=True))
    assert [n.score for n in last.nodes] == [n.score for n in policy.last_plan.nodes]


class Counter:
    """A policy that counts its calls and acts with its id."""

    name = "counter"

    def __init__(self, tag: float) -> None:
        self.tag, self.single, self.batches = tag, 0, []

    def reset(self) -> None:
        pass

    def act(self, obs, goal):
        self.single += 1
        return np.full((2, 4), self.tag)


class BatchCounter(Counter):
    def act_batch(self, observations, goals):
        self.batches.append(len(observations))
        return [np.full((2, 4), self.tag + i) for i in range(len(observations))]


def test_act_all_batches_environments_that_share_a_batch_policy():
    shared, own_a, own_b = BatchCounter(10.0), Counter(1.0), Counter(2.0)
    policies = [shared, own_a, shared, own_b, shared]
    actions = act_all(policies, [{}] * 5, [{}] * 5)
    assert shared.batches == [3] and shared.single == 0 and own_a.single == own_b.single == 1
    assert [a[0, 0] for a in actions] == [10.0, 1.0, 11.0, 2.0, 12.0]  # in the environments' order


@pytest.fixture(scope="module")
def scenes():
    """First observations and goals of four stack-tower episodes (validation seeds)."""
    env = SimEnvFactory()(get_task("stack-tower"))
    pairs = [env.reset(seed=s) for s in (1, 3, 5, 7)]
    return [o for o, _ in pairs], [info["goal"] for _, info in pairs]


@pytest.mark.parametrize("method", ["gctn", "tvf-small"])
def test_shipped_weights_decide_the_same_when_environments_share_model_calls(scenes, method):
    """The GPU's way (rows of several environments in one call) on the CPU: its convolutions round
    differently with the batch, yet no decision of the shipped lite models flips."""
    policy = make_policy(PolicySpec(method, device="cpu"))
    if method == "gctn":
        policy.mix = True
    else:
        policy.search.mix_roots = True
    obs, goals = scenes
    batched = policy.act_batch(obs, goals)
    single = [policy.act(o, g) for o, g in zip(obs, goals, strict=True)]
    assert all(np.array_equal(a, b) for a, b in zip(batched, single, strict=True))
