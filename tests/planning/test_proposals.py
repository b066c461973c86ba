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
    with_extra_place,
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


# --- Boundaries, settings and exact outputs (each of these kills a mutant that the tests above let live) ---


def _ring(n: int = 40) -> torch.Tensor:
    """Candidates evenly round a circle (distinct values, best first by index): K-means has many equally
    good splits, so the seed decides which one comes back."""
    logits = torch.full((4, 48, 48), LOW)
    for i in range(n):
        a = 2 * np.pi * i / n
        logits[i % 4, int(round(24 + 15 * np.sin(a))), int(round(24 + 15 * np.cos(a)))] = -0.001 * i / n
    return logits


def _square_and_a_far_pixel(top_n: int) -> torch.Tensor:
    """``top_n`` candidates in one square blob (a 10 x 10 one for the default) and, next in rank, one far
    pixel: K-means gives the far pixel its own proposal only when it is among the candidates."""
    side = int(np.sqrt(top_n))
    assert side * side == top_n
    logits = torch.full((4, 64, 64), LOW)
    order = torch.randperm(top_n, generator=torch.Generator().manual_seed(0)).float()
    logits[1, 5 : 5 + side, 5 : 5 + side] = (-0.001 * order / top_n).reshape(side, side)
    logits[2, 60, 60] = -0.01
    return logits


def _same(a, b) -> bool:
    return (
        a.places.tolist() == b.places.tolist()
        and a.rotations.tolist() == b.rotations.tolist()
        and a.logits.tolist() == b.logits.tolist()
    )


def test_the_rules_default_to_the_planners_settings():
    """Called without settings, every entry point uses PlannerConfig's alpha, top_n and seed and the
    kmeans rule; the data are chosen so that top_n + 1 and another seed would give other proposals."""
    from tvf.planning.search import PlannerConfig

    cfg = PlannerConfig()
    for logits in (_ring(), _square_and_a_far_pixel(cfg.top_n)):
        ref = state_proposals(logits, 2, alpha=cfg.alpha, top_n=cfg.top_n, seed=cfg.seed)
        assert _same(state_proposals(logits, 2), ref)
        assert _same(rule_proposals(logits, 2), ref)
        assert _same(place_proposals(logits[None], 2)[0], ref)
    ring, square = _ring(), _square_and_a_far_pixel(cfg.top_n)
    assert not _same(state_proposals(ring, 2, seed=cfg.seed + 1), state_proposals(ring, 2, seed=cfg.seed))
    assert [60, 60] not in state_proposals(square, 2).places.tolist()
    assert [60, 60] in state_proposals(square, 2, top_n=cfg.top_n + 1).places.tolist()


@pytest.mark.parametrize("seed", [1, 3, 5])
def test_rule_and_batch_entry_points_pass_every_setting_on(seed: int):
    ring = _ring()
    direct = state_proposals(ring, 2, alpha=0.02, top_n=30, seed=seed)
    assert not _same(direct, state_proposals(ring, 2, alpha=0.02, top_n=30, seed=0))  # the seed matters
    assert _same(rule_proposals(ring, 2, rule="kmeans", alpha=0.02, top_n=30, seed=seed), direct)
    batch = torch.stack([ring, _ring(24)])
    for b, p in enumerate(place_proposals(batch, 2, alpha=0.02, top_n=30, seed=seed)):
        assert _same(p, state_proposals(batch[b], 2, alpha=0.02, top_n=30, seed=seed))
    square = _square_and_a_far_pixel(100)[None]  # the far pixel is 0.99 times as likely as the best
    assert [60, 60] in place_proposals(square, 2, top_n=101)[0].places.tolist()
    assert [60, 60] not in place_proposals(square, 2, alpha=0.995, top_n=101)[0].places.tolist()
    nms = place_proposals(batch, 5, rule="nms", radius=3.0)
    for b, p in enumerate(nms):
        assert _same(p, nms_proposals(batch[b], 5, radius=3.0))
        assert _pairwise(p.places).min() < BLOCK_PIXELS  # the radius given, not the default


@pytest.mark.parametrize("rule", ["kmeans", "nms"])
def test_one_proposal_carries_the_logit_at_the_greedy_place(rule: str):
    logits = torch.randn(4, 12, 20, generator=torch.Generator().manual_seed(7))
    p = rule_proposals(logits, 1, rule=rule)
    c, (u, v) = int(p.rotations[0]), p.places[0]
    assert p.logits.tolist() == [float(logits.max())] == [float(logits[c, u, v])]
    assert p.places.dtype == np.int64 and p.rotations.dtype == np.int64


def test_kmeans_proposals_are_integer_pixels_and_channels():
    p = state_proposals(_ring(), 3)
    assert p.places.dtype == np.int64 and p.rotations.dtype == np.int64 and p.logits.dtype == np.float64


@pytest.mark.parametrize("rule", ["kmeans", "nms"])
def test_alpha_one_keeps_exactly_the_tied_best_places(rule: str):
    """The threshold is inclusive: with alpha = 1 the places as likely as the best (a tie) stay."""
    logits = _blank(h=32, w=32)
    logits[0, 3, 3] = 1.0
    logits[2, 25, 25] = 1.0  # tied with the best, far away
    logits[1, 14, 14] = 1.0 - 1e-4  # a hair below
    p = rule_proposals(logits, 3, rule=rule, alpha=1.0)
    assert sorted(p.places.tolist()) == [[3, 3], [25, 25]]
    assert sorted(p.rotations.tolist()) == [0, 2]
    assert len(rule_proposals(logits, 3, rule=rule, alpha=0.5)) == 3


def test_pick_peaks_alpha_one_and_the_radius_boundary():
    logits = torch.full((32, 32), LOW)
    logits[4, 4] = 2.0
    logits[4 + 3, 4 + 4] = 1.5  # exactly 5 pixels away: "at least radius apart" keeps it
    logits[6, 7] = 1.9  # 3.6 pixels from the best: suppressed
    logits[20, 20] = 2.0  # tied with the best
    assert pick_peaks(logits, 4, alpha=1.0).tolist() == [[4, 4], [20, 20]]
    assert pick_peaks(logits, 4, radius=5.0).tolist() == [[4, 4], [20, 20], [7, 8]]


def test_nms_radius_boundary_is_inclusive_and_one_pixel_is_the_smallest_radius():
    logits = _blank(h=16, w=16)
    logits[0, 2, 2] = 0.0
    logits[1, 5, 6] = -0.5  # exactly 5 pixels from the best: kept
    logits[2, 4, 5] = -0.1  # 3.6 pixels: suppressed
    logits[3, 2, 3] = -0.2  # the next pixel
    p = nms_proposals(logits, 4, radius=5.0)
    assert p.places.tolist() == [[2, 2], [5, 6]] and p.rotations.tolist() == [0, 1]
    one = nms_proposals(logits, 4, radius=1.0)  # suppresses the accepted pixel only
    assert one.places.tolist() == [[2, 2], [4, 5], [2, 3], [5, 6]]
    with pytest.raises(ValueError, match=r"^the NMS radius must be positive, got 0\.0$"):
        nms_proposals(logits, 2, radius=0.0)


@pytest.mark.parametrize("channels, period", [(36, None), (9, 90.0)])
def test_rotation_tolerance_boundary_one_channel_each_way(channels: int, period: float | None):
    """Channels step 10 degrees; with a tolerance of exactly 10 the neighbouring channels on both sides
    are the same placement (suppressed) and the channel two steps away is not. The accepted entry is at
    the last pixel, so its channel is read from the flat index exactly or not at all."""
    logits = torch.full((channels, 16, 16), LOW)
    c = 4
    logits[c, 15, 15] = 0.0
    logits[c + 1, 15, 15] = -0.1
    logits[c - 1, 15, 15] = -0.2
    logits[c + 2, 15, 15] = -0.3
    settings = {} if period is None else {"period": period}  # None: the default full turn
    for p in (
        nms_proposals(logits, 4, rotation_tolerance=10.0, **settings),
        rule_proposals(logits, 4, rule="nms", rotation_tolerance=10.0, **settings),
    ):
        assert p.places.tolist() == [[15, 15], [15, 15]] and p.rotations.tolist() == [c, c + 2]


def test_turn_difference_defaults_to_a_full_turn():
    assert turn_difference(0, 18, 36) == 180.0 and turn_difference(35, 0, 36) == 10.0


def test_node_proposals_with_three_picks_keep_picks_places_and_logits_in_step():
    logits = torch.stack([_smooth_logits(s) for s in (1, 2, 3)])
    picks = np.array([[5, 5], [40, 40], [20, 50]])
    p = node_proposals(logits, picks, k=5, rule="nms", alpha=1e-4)
    assert p.picks.tolist() == [[5, 5], [40, 40], [20, 50], [5, 5], [5, 5]]
    assert len(p.places) == len(p.rotations) == len(p.logits) == 5
    assert p.places.dtype == p.rotations.dtype == p.picks.dtype == np.int64 and p.logits.dtype == np.float64
    owner = [0, 1, 2, 0, 0]
    for j, ((u, v), c, value) in enumerate(zip(p.places, p.rotations, p.logits, strict=True)):
        assert value == pytest.approx(float(logits[owner[j], c, u, v]))
    assert p.logits[0] == float(logits[0].max()) and p.logits[2] == float(logits[2].max())


def test_bad_logits_and_settings_get_exact_messages():
    bad = _blank()
    bad[0, 0, 0] = float("inf")
    with pytest.raises(
        ValueError, match=r"^place logits contain NaN or infinity; the GCTN input is corrupt$"
    ):
        nms_proposals(bad, 2)
    with pytest.raises(ValueError, match=r"^pick logits contain NaN or infinity; the GCTN input is corrupt$"):
        pick_peaks(bad[0], 2)
    with pytest.raises(ValueError, match=r"^n must be at least 1, got 0$"):
        pick_peaks(_blank()[0], 0)
    with pytest.raises(ValueError, match=r"^unknown proposal rule 'topk'; choose one of kmeans, nms$"):
        rule_proposals(_blank(), 2, rule="topk")


@pytest.mark.parametrize("seed", range(4))
def test_kmeans_plus_plus_never_draws_a_chosen_point_again(seed: int):
    """k = n distinct points: k-means++ gives every point its own centre (a chosen point has weight 0)."""
    points = np.random.default_rng(100 + seed).uniform(0, 20, (6, 2))
    labels, centres = kmeans(points, 6, np.random.default_rng(seed), n_init=1)
    assert sorted(labels.tolist()) == list(range(6))
    assert np.array_equal(centres[labels], points)


def test_kmeans_single_runs_end_at_lloyds_fixed_point():
    """Small overlapping clusters, one restart each: every centre is the mean of its points, none empty."""
    for s in range(30):
        points = np.random.default_rng(200 + s).normal(0, 1, (12, 2)) + 5
        labels, centres = kmeans(points, 5, np.random.default_rng(s), n_init=1)
        for j in range(5):
            assert (labels == j).any()
            assert centres[j] == pytest.approx(points[labels == j].mean(axis=0), abs=1e-9)


def test_kmeans_keeps_the_best_of_its_restarts():
    """Six overlapping clusters: single runs often stop in a local optimum; the best of 10 restarts is as
    tight as the best of 10 separate single runs."""
    for d in range(6):
        rng = np.random.default_rng(300 + d)
        points = np.concatenate([rng.normal(c, 1.0, (15, 2)) for c in rng.uniform(0, 8, (6, 2))])
        single = [
            _inertia(points, kmeans(points, 6, np.random.default_rng(q), n_init=1)[1]) for q in range(10)
        ]
        labels, centres = kmeans(points, 6, np.random.default_rng(d), n_init=10)
        assert _inertia(points, centres) <= min(single) * (1 + 1e-6)
        assert (labels == ((points[:, None] - centres[None]) ** 2).sum(-1).argmin(1)).all()


def test_an_extra_place_fills_a_missing_proposal_or_replaces_the_last_unless_already_proposed():
    logits = _blank()
    logits[1, 3, 3], logits[2, 12, 12] = 0.0, -1.0  # two places at the best pick
    props = node_proposals(logits[None], np.array([[8, 8]]), 2, rule="nms", radius=4.0)
    assert props.places.tolist() == [[3, 3], [12, 12]]
    extra = _blank()
    extra[3, 8, 2] = -7.0  # the extra rule's best place: 5 px from the first proposal
    replaced = with_extra_place(props, extra, np.array([8, 8]), 2, radius=4.0)
    assert replaced.places.tolist() == [[3, 3], [8, 2]] and replaced.rotations.tolist() == [1, 3]
    assert replaced.logits.tolist() == [0.0, -7.0] and replaced.picks.tolist() == [[8, 8], [8, 8]]
    appended = with_extra_place(props, extra, np.array([8, 8]), 3, radius=4.0)
    assert appended.places.tolist() == [[3, 3], [12, 12], [8, 2]]
    assert with_extra_place(props, extra, np.array([8, 8]), 2, radius=6.0) is props  # already proposed
    assert with_extra_place(props, extra, np.array([8, 8]), 1, radius=4.0) is props  # greedy stays
    one = rule_proposals(logits, 1)  # no picks recorded: the node's one pick is filled in
    filled = with_extra_place(one, extra, np.array([5, 6]), 2, radius=4.0)
    assert filled.picks.tolist() == [[5, 6], [5, 6]] and filled.places.tolist() == [[3, 3], [8, 2]]
