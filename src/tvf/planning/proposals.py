"""Multi-modal place proposals from a GCTN transport map (TVF's top-K actions).

For each state: ``M(u, v)`` = max over rotations of the place logits (with the best rotation kept);
pixels whose softmax value is below ``alpha`` times the best are dropped (in logits: ``M < max M +
log alpha``); the ``top_n`` best remaining pixels are clustered by their (row, col) with seeded K-means;
each cluster gives its best pixel and that pixel's best rotation. ``k = 1`` is the global argmax, i.e.
exactly GCTN's greedy place. Fewer distinct candidate pixels than ``k`` give fewer proposals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from tvf.models.gctn import argmax_places


@dataclass(frozen=True)
class Proposals:
    """Place proposals of one state, best first: pixels (n, 2) (row, col), place-map rotation channels
    (n,), logits (n,)."""

    places: np.ndarray
    rotations: np.ndarray
    logits: np.ndarray

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


def state_proposals(
    logits: torch.Tensor, k: int, alpha: float = 0.01, top_n: int = 100, seed: int = 0, n_init: int = 10
) -> Proposals:
    """Proposals from one state's place logits (R, H, W); a pure function of its inputs."""
    if k < 1:
        raise ValueError(f"k must be at least 1, got {k}")
    if not torch.isfinite(logits).all():
        raise ValueError("place logits contain NaN or infinity; the GCTN input is corrupt")
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


def place_proposals(
    place_logits: torch.Tensor, k: int, alpha: float = 0.01, top_n: int = 100, seed: int = 0
) -> list[Proposals]:
    """:func:`state_proposals` for each state of a batch of place logits (B, R, H, W)."""
    logits = place_logits.detach().float().cpu()
    return [state_proposals(logits[b], k, alpha, top_n, seed) for b in range(logits.shape[0])]
