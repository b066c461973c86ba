"""Multi-modal place proposals: argmax equivalence, clustering, NMS, pick branching, edge cases."""

import numpy as np
import pytest
import torch

from tvf.models.gctn import GCTN, argmax_places
from tvf.models.presets import get_preset
from tvf.planning.proposals import (
    BLOCK_PIXELS,
    kmeans,
    nms_proposals,
    node_proposals,
    pick_peaks,
    place_proposals,
    rule_proposals,
    state_proposals,
    turn_difference,
)

LOW = -100.0


def _blank(r: int = 4, h: int = 16, w: int = 16) -> torch.Tensor:
    return torch.full((r, h, w), LOW)


@pytest.mark.parametrize("rule", ["kmeans", "nms"])
def test_k1_is_the_gctn_greedy_place(rule: str):
    torch.manual_seed(0)
    model = GCTN(get_preset("smoke"), seed=0).eval()
    current, goal = torch.randn(2, 4, 160, 160), torch.randn(2, 4, 160, 160)
    pick, place, rot, maps = model.act(current, goal)
    for b, p in enumerate(place_proposals(maps["place"], k=1, rule=rule)):
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


def _inertia(points: np.ndarray, centres: np.ndarray) -> float:
    return float(((points[:, None] - centres[None]) ** 2).sum(-1).min(1).sum())


@pytest.mark.parametrize("seed", range(3))
def test_kmeans_on_overlapping_clusters_is_lloyds_fixed_point_as_good_as_scipys(seed: int):
    """Three clusters 1.2 to 2.5 sigma apart: the centres must move (each is the mean of its points, each
    point is nearest its own centre) and the clustering is as tight as scipy's best of 30 runs."""
    from scipy.cluster.vq import kmeans2

    rng = np.random.default_rng(seed)
    points = np.concatenate([rng.normal(c, 1.0, (40, 2)) for c in ([0, 0], [2.5, 0], [1.2, 2.2])])
    labels, centres = kmeans(points, 3, np.random.default_rng(seed))
    for j in range(3):
        assert centres[j] == pytest.approx(points[labels == j].mean(axis=0), abs=1e-9)
    nearest = ((points[:, None] - centres[None]) ** 2).sum(-1).argmin(1)
    assert (labels == nearest).all()
    best = min(
        _inertia(points, kmeans2(points, 3, iter=100, minit="++", rng=np.random.default_rng(s))[0])
        for s in range(30)
    )
    assert _inertia(points, centres) <= best * (1 + 1e-3)


def _pairwise(points: np.ndarray) -> np.ndarray:
    d = np.hypot(*(points[:, None] - points[None]).transpose(2, 0, 1)).astype(float)
    return d[np.triu_indices(len(points), 1)]


def _smooth_logits(seed: int, r: int = 9, size: int = 64) -> torch.Tensor:
    """Random place logits with blob-like peaks (a smoothed random field), like a real place map."""
    gen = torch.Generator().manual_seed(seed)
    noise = torch.randn(1, r, size, size, generator=gen)
    kernel = torch.ones(r, 1, 9, 9) / 81
    return 10 * torch.nn.functional.conv2d(noise, kernel, padding=4, groups=r)[0]


@pytest.mark.parametrize("seed", range(4))
def test_nms_places_are_a_block_apart_best_first_and_the_first_is_the_argmax(seed: int):
    logits = _smooth_logits(seed)
    p = nms_proposals(logits, k=6, alpha=1e-4)
    assert len(p) == 6
    assert (_pairwise(p.places) >= BLOCK_PIXELS).all()
    place, rot = argmax_places(logits[None])
    assert p.places[0].tolist() == place[0].tolist() and p.rotations[0] == rot[0]
    assert (np.diff(p.logits) <= 0).all()
    for (u, v), c, value in zip(p.places, p.rotations, p.logits, strict=True):
        assert value == pytest.approx(float(logits[c, u, v]))
        assert value == pytest.approx(float(logits[:, u, v].max()))  # each place's best rotation


def test_nms_respects_alpha_and_gives_fewer_proposals_when_candidates_run_out():
    logits = _blank()
    logits[0, 2, 2] = 0.0
    logits[1, 12, 12] = np.log(0.5)  # far away, half as likely: a proposal
    logits[2, 3, 3] = np.log(0.9)  # next to the best: suppressed
    logits[3, 2, 12] = np.log(0.005)  # below alpha = 1%: never proposed
    p = nms_proposals(logits, k=4, radius=5.0)
    assert p.places.tolist() == [[2, 2], [12, 12]] and p.rotations.tolist() == [0, 1]
    assert len(nms_proposals(logits, k=4, alpha=0.001, radius=5.0)) == 3


def test_nms_splits_what_kmeans_clusters_in_one_blob():
    """The measured problem: the top 100 pixels all lie in the best blob, so K-means splits that blob."""
    rows, cols = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
    blob = lambda r, c, s: -((rows - r) ** 2 + (cols - c) ** 2) / (2 * s**2)  # noqa: E731
    logits = torch.maximum(blob(20, 20, 8.0), blob(50, 45, 2.0) - 1.0).expand(4, 64, 64).clone()
    km = state_proposals(logits, k=3)
    assert (_pairwise(km.places) < BLOCK_PIXELS).any()  # two of K-means' three in one blob
    nms = nms_proposals(logits, k=3)
    assert [20, 20] in nms.places.tolist() and [50, 45] in nms.places.tolist()
    assert (_pairwise(nms.places) >= BLOCK_PIXELS).all()


def test_turn_difference_is_modulo_the_period_of_the_channels():
    assert turn_difference(0, 4, 9, 90.0) == 40.0  # lite: channels 0 and 4 are 0 and 40 degrees
    assert turn_difference(4, 5, 9, 90.0) == 10.0  # 40 and -40 degrees: 10 apart for a cube
    assert turn_difference(0, 18, 36, 360.0) == 180.0
    assert turn_difference(1, 35, 36, 360.0) == 20.0


def test_rotation_tolerance_makes_a_turned_place_at_the_same_pixel_distinct():
    logits = torch.full((9, 32, 32), LOW)  # the lite layout: 9 channels of a 90-degree period
    logits[0, 10, 10] = 0.0  # no turn
    logits[1, 10, 10] = -0.1  # 10 degrees: the same placement
    logits[4, 10, 11] = -0.5  # 40 degrees, next pixel: a different placement
    logits[5, 10, 10] = -0.6  # -40 degrees = 10 degrees from channel 4
    assert len(nms_proposals(logits, k=3)) == 1  # default: rotation never separates
    p = nms_proposals(logits, k=3, rotation_tolerance=30.0, period=90.0)
    assert p.places.tolist() == [[10, 10], [10, 11]] and p.rotations.tolist() == [0, 4]
    assert len(nms_proposals(logits, k=4, rotation_tolerance=5.0, period=90.0)) == 4


def test_pick_peaks_are_distinct_blocks_above_alpha():
    logits = torch.full((64, 64), LOW)
    logits[10:14, 10:14] = 1.0  # block A: its top face
    logits[11, 12] = 2.0
    logits[30:34, 40:44] = 1.5  # block B
    logits[50, 5] = 2.0 + np.log(0.001)  # improbable
    picks = pick_peaks(logits, 3)
    assert picks.tolist() == [[11, 12], [30, 40]]  # A's best pixel, then B's first best pixel
    assert pick_peaks(logits, 1).tolist() == [[11, 12]]
    assert len(pick_peaks(logits, 3, alpha=1e-4)) == 3
    dense = _smooth_logits(0, r=1)[0]
    assert (_pairwise(pick_peaks(dense, 5, alpha=1e-6)) >= BLOCK_PIXELS).all()


def test_node_proposals_share_k_between_picks_best_pick_first():
    logits = torch.stack([_smooth_logits(1), _smooth_logits(2)])  # place maps at two picks
    picks = np.array([[5, 5], [40, 40]])
    p = node_proposals(logits, picks, k=4, rule="nms", alpha=1e-4)
    assert p.picks.tolist() == [[5, 5], [40, 40], [5, 5], [5, 5]]
    at_best = nms_proposals(logits[0], 3, alpha=1e-4)
    greedy, rot = argmax_places(logits[1:])
    assert p.places[[0, 2, 3]].tolist() == at_best.places.tolist()
    assert p.places[1].tolist() == greedy[0].tolist() and p.rotations[1] == rot[0]
    two = node_proposals(logits, picks, k=2, rule="kmeans")
    assert two.picks.tolist() == picks.tolist()  # k = P: the best place at each pick
    one = node_proposals(logits[:1], picks[:1], k=3, rule="kmeans", seed=4)
    ref = state_proposals(logits[0], 3, seed=4)  # one pick: the rule's proposals, unchanged
    assert one.places.tolist() == ref.places.tolist() and one.rotations.tolist() == ref.rotations.tolist()
    with pytest.raises(ValueError, match="picks <= k"):
        node_proposals(logits, picks, k=1)
    with pytest.raises(ValueError, match="unknown proposal rule"):
        rule_proposals(logits[0], 2, rule="topk")
