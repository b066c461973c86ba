"""A search over N roots at once (N environments) gives the plans of N single searches."""

import numpy as np
import pytest
import torch

from tvf.models.gctn import GCTN
from tvf.models.presets import get_preset
from tvf.models.symmetry import symmetrized
from tvf.models.vf import VisualForesight
from tvf.planning.search import PlannerConfig, TreeSearch

CONFIGS = {
    "kmeans": (PlannerConfig(k=2, depth=2), 1),
    "nms-picks": (PlannerConfig(k=3, depth=2, proposals="nms", pick_branches=2), 1),
    "turns-root": (PlannerConfig(k=2, depth=2, proposals="nms", pick_branches=2, turns_depth=1), 2),
}


@pytest.fixture(scope="module")
def models():
    preset = get_preset("smoke").replace(symmetry=4)
    return GCTN(preset, seed=3).eval(), VisualForesight(preset, seed=4).eval()


def _scenes(n: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(n, 4, 160, 160, generator=g), torch.randn(n, 4, 160, 160, generator=g)


def _actions(plan) -> list[tuple]:
    return [(n.parent, n.depth, tuple(n.pick), tuple(n.place), n.rotation) for n in plan.nodes]


@pytest.mark.parametrize("name", list(CONFIGS))
def test_n_roots_plan_exactly_as_n_single_searches_when_roots_stay_apart(models, name):
    config, turns = CONFIGS[name]
    gctn, vf = symmetrized(models[0], turns), models[1]
    currents, goals = _scenes(3)
    search = TreeSearch(gctn, vf, config, mix_roots=False)
    many = search.search_many(currents, goals, keep_images=True)
    for i, plan in enumerate(many):
        alone = search.search(currents[i : i + 1], goals[i : i + 1], keep_images=True)
        assert _actions(plan) == _actions(alone)
        assert [n.score for n in plan.nodes] == [n.score for n in alone.nodes]  # bit for bit
        assert plan.best == alone.best and plan.counts == alone.counts
        assert torch.equal(plan.images, alone.images)
        assert torch.equal(plan.pick_logits, alone.pick_logits)
        assert torch.equal(plan.place_logits, alone.place_logits)
    assert len({_actions(p)[0] for p in many}) > 1  # the roots really differ


@pytest.mark.parametrize("name", list(CONFIGS))
def test_roots_mixed_in_one_model_call_give_the_same_actions(models, name):
    config, turns = CONFIGS[name]
    gctn, vf = symmetrized(models[0], turns), models[1]
    currents, goals = _scenes(4, seed=1)
    mixed = TreeSearch(gctn, vf, config, mix_roots=True).search_many(currents, goals)
    single = TreeSearch(gctn, vf, config, mix_roots=False)
    for i, plan in enumerate(mixed):
        alone = single.search(currents[i : i + 1], goals[i : i + 1])
        assert _actions(plan) == _actions(alone)
        np.testing.assert_allclose([n.score for n in plan.nodes], [n.score for n in alone.nodes], atol=1e-5)
        assert plan.best == alone.best


def test_one_call_per_level_covers_every_root_when_mixed(models):
    calls = []
    gctn, vf = models

    class Counting:
        def __init__(self, vf):
            self.vf = vf

        def predict_rgbh(self, states, *args):
            calls.append(states.shape[0])
            return self.vf.predict_rgbh(states, *args)

    currents, goals = _scenes(3, seed=2)
    TreeSearch(gctn, Counting(vf), PlannerConfig(k=2, depth=2), mix_roots=True).search_many(currents, goals)
    assert calls == [6, 12]  # one VF call per level over the 3 trees (chunked inside the model)
    calls.clear()
    TreeSearch(gctn, Counting(vf), PlannerConfig(k=2, depth=2), mix_roots=False).search_many(currents, goals)
    assert calls == [2, 2, 2, 4, 4, 4]  # one per root and level: the calls of three single searches


def test_roots_and_goals_must_pair_up(models):
    currents, goals = _scenes(2)
    with pytest.raises(ValueError, match="2 states but 1 goals"):
        TreeSearch(*models, PlannerConfig(k=2, depth=1)).search_many(currents, goals[:1])
