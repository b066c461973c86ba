"""Multi-modal place proposals: argmax equivalence, clustering, edge cases."""

import numpy as np
import pytest
import torch

from tvf.models.gctn import GCTN
from tvf.models.presets import get_preset
from tvf.planning.proposals import kmeans, place_proposals, state_proposals

LOW = -100.0


def _blank(r: int = 4, h: int = 16, w: int = 16) -> torch.Tensor:
    return torch.full((r, h, w), LOW)


def test_k1_is_the_gctn_greedy_place():
    torch.manual_seed(0)
    model = GCTN(get_preset("smoke"), seed=0).eval()
    current, goal = torch.randn(2, 4, 160, 160), torch.randn(2, 4, 160, 160)
    pick, place, rot, maps = model.act(current, goal)
    for b, p in enumerate(place_proposals(maps["place"], k=1)):
        assert len(p) == 1
        assert p.places[0].tolist() == place[b].tolist() and p.rotations[0] == rot[b]


def test_two_blobs_give_one_proposal_each_best_first_with_its_best_rotation():
    logits = _blank()
    logits[1, 2:4, 2:4] = 0.0  # blob A, rotation 1
    logits[3, 12:14, 11:13] = 0.5  # blob B, better, rotation 3
    logits[2, 13, 12] = 0.9  # B's best pixel prefers rotation 2
    p = state_proposals(logits, k=2)
    assert len(p) == 2
    assert p.places[0].tolist() == [13, 12] and p.rotations[0] == 2
    assert 2 <= p.places[1][0] < 4 and 2 <= p.places[1][1] < 4 and p.rotations[1] == 1
    assert p.logits[0] > p.logits[1]


def test_threshold_drops_improbable_pixels_so_fewer_proposals_come_back():
    logits = _blank()
    logits[0, 5, 5] = 0.0
    logits[0, 10, 10] = np.log(0.005)  # 0.5% of the best: below alpha = 1%
    p = state_proposals(logits, k=3)
    assert len(p) == 1 and p.places[0].tolist() == [5, 5]
    assert len(state_proposals(logits, k=3, alpha=0.001)) == 2


def test_top_n_limits_the_candidates():
    logits = _blank()
    logits[0, 0, :] = torch.linspace(1.0, 0.9, 16)  # 16 near-equal pixels in row 0
    logits[0, 15, 15] = 0.8
    p = state_proposals(logits, k=2, top_n=16)
    assert all(row == 0 for row, _ in p.places)  # the far pixel is not among the top 16


def test_proposals_are_deterministic_and_reject_nan():
    logits = torch.randn(4, 16, 16)
    a, b = state_proposals(logits, 3, seed=5), state_proposals(logits, 3, seed=5)
    assert a.places.tolist() == b.places.tolist() and a.rotations.tolist() == b.rotations.tolist()
    logits[0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        state_proposals(logits, 2)
    with pytest.raises(ValueError, match="k must be"):
        state_proposals(torch.zeros(4, 8, 8), 0)


def test_kmeans_separates_clear_clusters():
    rng = np.random.default_rng(0)
    points = np.concatenate([rng.normal(0, 1, (30, 2)), rng.normal(50, 1, (30, 2))])
    labels, centres = kmeans(points, 2, np.random.default_rng(1))
    assert len(set(labels[:30])) == 1 and len(set(labels[30:])) == 1 and labels[0] != labels[-1]
    assert sorted(np.round(centres[:, 0] / 50).tolist()) == [0.0, 1.0]
