"""Multi-modal place proposals from a GCTN transport map (TVF's top-K actions), and pick branching.

Two rules pick K proposals from one state's place logits ``(R, H, W)``; both drop candidates whose
softmax value is below ``alpha`` times the best (in logits: below ``max + log alpha``), both return
the global argmax first (``k = 1`` is exactly GCTN's greedy place), and both return fewer than K
proposals when fewer distinct candidates survive the threshold.

* ``kmeans`` (the paper): ``M(u, v)`` = max over rotations (with the best rotation kept); the
  ``top_n`` best pixels above the threshold are clustered by their (row, col) with seeded K-means;
  each cluster gives its best pixel and that pixel's best rotation.
* ``nms``: non-maximum suppression over (rotation channel, pixel): take the best remaining entry,
  then drop every entry within ``radius`` pixels of it (default one block), and repeat. With a
  ``rotation_tolerance`` (degrees) an entry near an accepted place survives when its turn differs
  from the accepted one by more than the tolerance (modulo the period the channels cover).

:func:`node_proposals` adds pick branching: the best place at each of several distinct picks
(:func:`pick_peaks`, NMS on the pick logits), then the rule's further places at the best pick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from tvf.models.gctn import argmax_places

RULES = ("kmeans", "nms")
"""Proposal rules: the paper's K-means clustering, or non-maximum suppression."""

BLOCK_PIXELS = 13.0
"""One block in pixels: a 4 cm cube at 3.125 mm per pixel is 12.8 px. The default NMS radius."""


@dataclass(frozen=True)
class Proposals:
    """Place proposals of one state, best first: pixels (n, 2) (row, col), place-map rotation channels
    (n,), logits (n,) of each place in its own pick's place map, and picks (n, 2) (None: every
    proposal uses the state's one pick)."""

    places: np.ndarray
    rotations: np.ndarray
    logits: np.ndarray
    picks: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.rotations)


def kmeans(points: np.ndarray, k: int, rng: np.random.Generator, n_init: int = 10, iters: int = 100):
    """Lloyd's K-means with k-means++ seeding, best of ``n_init`` restarts (all restarts vectorised).

    ``points`` (n, 2) float with at least ``k`` distinct rows. Returns labels (n,) and centres (k, 2).
    """
    n = len(points)
    centres = np.empty((n_init, k, points.shape[1]))
    centres[:, 0] = points[rng.integers(n, size=n_init)]
    nearest = ((points[None] - centres[:, :1]) ** 2).sum(-1)  # (n_init, n) squared distance to the centres
    for j in range(1, k):  # k-means++: draw the next centre with probability ~ squared distance
        weights = nearest / nearest.sum(axis=1, keepdims=True)
        draws = [rng.choice(n, p=w) for w in weights]
        centres[:, j] = points[draws]
        nearest = np.minimum(nearest, ((points[None] - centres[:, j : j + 1]) ** 2).sum(-1))
    for _ in range(iters):
        distances = ((points[None, :, None] - centres[:, None]) ** 2).sum(-1)  # (n_init, n, k)
        labels = distances.argmin(-1)
        one_hot = labels[..., None] == np.arange(k)  # (n_init, n, k)
        counts = one_hot.sum(1)  # (n_init, k)
        sums = np.einsum("snk,nd->skd", one_hot.astype(float), points)
        moved = np.where(counts[..., None] > 0, sums / np.maximum(counts, 1)[..., None], centres)
        if np.allclose(moved, centres):
            break
        centres = moved
    distances = ((points[None, :, None] - centres[:, None]) ** 2).sum(-1)
    inertia = distances.min(-1).sum(-1)
    best = int(inertia.argmin())
    return distances[best].argmin(-1), centres[best]


def _greedy(logits: torch.Tensor) -> Proposals:
    """The GCTN's own choice (:func:`tvf.models.gctn.argmax_places`) as a single proposal."""
    place, rot = argmax_places(logits[None])
    value = float(logits[rot[0], place[0, 0], place[0, 1]])
    return Proposals(place.numpy(), rot.numpy(), np.array([value]))


def _check(logits: torch.Tensor, k: int) -> None:
    if k < 1:
        raise ValueError(f"k must be at least 1, got {k}")
    if not torch.isfinite(logits).all():
        raise ValueError("place logits contain NaN or infinity; the GCTN input is corrupt")


def state_proposals(
    logits: torch.Tensor, k: int, alpha: float = 0.01, top_n: int = 100, seed: int = 0, n_init: int = 10
) -> Proposals:
    """Proposals of the ``kmeans`` rule from one state's place logits (R, H, W); a pure function."""
    _check(logits, k)
    if k == 1:
        return _greedy(logits)
    best, rotation = logits.max(dim=0)  # (H, W)
    w = best.shape[1]
    flat = best.reshape(-1)
    keep = flat >= flat.max() + math.log(alpha)
    n = int(min(top_n, int(keep.sum())))
    values, index = torch.topk(torch.where(keep, flat, torch.tensor(-math.inf)), n)
    index = index.numpy()
    pixels = np.stack([index // w, index % w], axis=1)
    values = values.numpy().astype(np.float64)
    clusters = min(k, len(np.unique(pixels, axis=0)))
    labels, _ = kmeans(pixels.astype(np.float64), clusters, np.random.default_rng(seed), n_init)
    chosen = [int(np.flatnonzero(labels == c)[0]) for c in range(clusters)]  # top-n is sorted: first = best
    chosen.sort(key=lambda i: -values[i])
    places = pixels[chosen]
    rotations = rotation.reshape(-1)[torch.as_tensor(index[chosen])].numpy()
    return Proposals(places.astype(np.int64), rotations.astype(np.int64), values[chosen])


def turn_difference(a: np.ndarray, b: np.ndarray, channels: int, period: float = 360.0) -> np.ndarray:
    """Unsigned turn (degrees) between place-map channels ``a`` and ``b`` of ``channels`` covering
    ``period`` degrees: channel c turns the object by c * period / channels modulo the period (true
    for the full-turn maps and for the symmetric ones, see :func:`tvf.models.gctn.channel_bins`)."""
    steps = np.mod(np.asarray(a) - np.asarray(b), channels)
    return np.minimum(steps, channels - steps) * (period / channels)


def _suppress_peaks(
    logits: torch.Tensor, n: int, alpha: float, radius: float, tolerance: float | None, period: float
) -> list[tuple[int, int, int, float]]:
    """Greedy NMS over (channel, row, col) of ``logits`` (R, H, W): up to ``n`` (channel, row, col, logit)."""
    if radius <= 0:
        raise ValueError(f"the NMS radius must be positive, got {radius}")
    r, h, w = logits.shape
    live = logits.clone()
    live[logits < logits.max() + math.log(alpha)] = -math.inf
    rows = torch.arange(h, dtype=torch.float64)[:, None]
    cols = torch.arange(w, dtype=torch.float64)[None, :]
    out: list[tuple[int, int, int, float]] = []
    while len(out) < n:
        flat = int(live.reshape(-1).argmax())  # the first maximum, as argmax_places
        value = float(live.reshape(-1)[flat])
        if value == -math.inf:
            break
        c, u, v = flat // (h * w), (flat // w) % h, flat % w
        out.append((c, u, v, value))
        near = (rows - u) ** 2 + (cols - v) ** 2 < radius**2  # (H, W)
        if tolerance is None:
            live[:, near] = -math.inf
        else:
            alike = turn_difference(np.arange(r), c, r, period) <= tolerance  # (R,)
            live[torch.as_tensor(alike)[:, None, None] & near[None]] = -math.inf
    return out


def nms_proposals(
    logits: torch.Tensor,
    k: int,
    alpha: float = 0.01,
    radius: float = BLOCK_PIXELS,
    rotation_tolerance: float | None = None,
    period: float = 360.0,
) -> Proposals:
    """Proposals of the ``nms`` rule from one state's place logits (R, H, W); a pure function.

    Accepted places are pairwise at least ``radius`` pixels apart; with ``rotation_tolerance`` (degrees)
    two places nearer than that may both come back when their turns differ by more than the tolerance
    (``period``: the degrees the R channels cover, 360 / symmetry).
    """
    _check(logits, k)
    if k == 1:
        return _greedy(logits)
    peaks = _suppress_peaks(logits, k, alpha, radius, rotation_tolerance, period)
    places = np.array([[u, v] for _, u, v, _ in peaks], dtype=np.int64)
    rotations = np.array([c for c, _, _, _ in peaks], dtype=np.int64)
    return Proposals(places, rotations, np.array([x for *_, x in peaks], dtype=np.float64))


def pick_peaks(
    pick_logits: torch.Tensor, n: int, alpha: float = 0.01, radius: float = BLOCK_PIXELS
) -> np.ndarray:
    """Up to ``n`` picks (m, 2) from pick logits (H, W), best first, pairwise >= ``radius`` apart and
    each with probability at least ``alpha`` times the best; ``n = 1`` is the argmax."""
    logits = pick_logits.detach().float().cpu()
    if not torch.isfinite(logits).all():
        raise ValueError("pick logits contain NaN or infinity; the GCTN input is corrupt")
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    peaks = _suppress_peaks(logits[None], n, alpha, radius, None, 360.0)
    return np.array([[u, v] for _, u, v, _ in peaks], dtype=np.int64)


def rule_proposals(
    logits: torch.Tensor,
    k: int,
    rule: str = "kmeans",
    alpha: float = 0.01,
    top_n: int = 100,
    seed: int = 0,
    radius: float = BLOCK_PIXELS,
    rotation_tolerance: float | None = None,
    period: float = 360.0,
) -> Proposals:
    """Proposals of ``rule`` (kmeans | nms) from one state's place logits (R, H, W)."""
    if rule == "kmeans":
        return state_proposals(logits, k, alpha, top_n, seed)
    if rule == "nms":
        return nms_proposals(logits, k, alpha, radius, rotation_tolerance, period)
    raise ValueError(f"unknown proposal rule {rule!r}; choose one of {', '.join(RULES)}")


def node_proposals(place_logits: torch.Tensor, picks: np.ndarray, k: int, **rule) -> Proposals:
    """K proposals of one state over several picks: place logits (P, R, H, W) at picks (P, 2), best first.

    With P picks (P <= k): the best place at each pick first (pick order; the first is the GCTN's
    greedy action), then ``k - P`` further places at the best pick by the rule (``rule``: the keyword
    arguments of :func:`rule_proposals`). With one pick this is :func:`rule_proposals` with picks added.
    """
    picks = np.asarray(picks, dtype=np.int64).reshape(-1, 2)
    n = len(picks)
    if not 1 <= n <= k or place_logits.shape[0] != n:
        raise ValueError(f"need 1 <= picks <= k = {k} and one place map per pick, got {n} picks")
    logits = place_logits.detach().float().cpu()
    at_best = rule_proposals(logits[0], k - n + 1, **rule)
    parts = [Proposals(at_best.places[:1], at_best.rotations[:1], at_best.logits[:1], picks[:1])]
    for j in range(1, n):
        _check(logits[j], 1)
        best = _greedy(logits[j])
        parts.append(Proposals(best.places, best.rotations, best.logits, picks[j : j + 1]))
    rest = slice(1, None)
    parts.append(Proposals(at_best.places[rest], at_best.rotations[rest], at_best.logits[rest],
                           np.repeat(picks[:1], len(at_best) - 1, axis=0)))  # fmt: skip
    return Proposals(
        np.concatenate([p.places for p in parts]).astype(np.int64),
        np.concatenate([p.rotations for p in parts]).astype(np.int64),
        np.concatenate([p.logits for p in parts]).astype(np.float64),
        np.concatenate([p.picks for p in parts]).astype(np.int64),
    )


def place_proposals(
    place_logits: torch.Tensor, k: int, alpha: float = 0.01, top_n: int = 100, seed: int = 0, **rule
) -> list[Proposals]:
    """:func:`rule_proposals` for each state of a batch of place logits (B, R, H, W) (default: kmeans)."""
    logits = place_logits.detach().float().cpu()
    return [
        rule_proposals(logits[b], k, alpha=alpha, top_n=top_n, seed=seed, **rule)
        for b in range(logits.shape[0])
    ]


def with_extra_place(props: Proposals, logits: torch.Tensor, pick: np.ndarray, k: int, radius: float
                     ) -> Proposals:  # fmt: skip
    """``props`` (with picks) and, at ``pick``, the best place of ``logits`` (R, H, W): appended when there
    are fewer than ``k`` proposals, else in place of the last one; unchanged when a proposal already lies
    within ``radius`` pixels of it, or when ``k`` is 1 (the greedy action stays)."""
    extra = _greedy(logits.detach().float().cpu())
    if k < 2 or np.hypot(*(props.places - extra.places[0]).T).min() < radius:
        return props
    keep = slice(0, min(len(props), k - 1))
    picks = props.picks if props.picks is not None else np.repeat(np.asarray(pick)[None], len(props), 0)
    return Proposals(
        np.concatenate([props.places[keep], extra.places]).astype(np.int64),
        np.concatenate([props.rotations[keep], extra.rotations]).astype(np.int64),
        np.concatenate([props.logits[keep], extra.logits]).astype(np.float64),
        np.concatenate([picks[keep], np.asarray(pick, dtype=np.int64).reshape(1, 2)]).astype(np.int64),
    )
