"""Synthetic episodes for the data tests (imported by conftest and the tests)."""

from __future__ import annotations

import numpy as np

from tvf.data import Episode
from tvf.geometry import WORKSPACE


def make_episode(
    task: str = "stack-stair", seed: int = 0, steps: int = 5, split: str = "train", rng_seed: int = 0
) -> Episode:
    """A synthetic episode with the documented shapes; steps 0 and 3 are random, actions inside."""
    rng = np.random.default_rng(rng_seed)
    h, w = WORKSPACE.shape
    n = 3
    xy = lambda k: np.stack([rng.uniform(0.33, 0.67, k), rng.uniform(-0.17, 0.17, k)], 1)  # noqa: E731
    pick = np.concatenate([xy(steps), rng.uniform(0, 0.1, (steps, 1)), np.zeros((steps, 1))], 1)
    place = np.concatenate([xy(steps), rng.uniform(0, 0.1, (steps, 1)), rng.uniform(-3, 3, (steps, 1))], 1)
    random = np.zeros(steps, bool)
    if split == "train":
        random[[i for i in (0, 3) if i < steps - 1]] = True
    return Episode(
        task=task,
        seed=seed,
        split=split,
        color=rng.integers(0, 256, (steps + 1, h, w, 3), dtype=np.uint8),
        height=rng.uniform(0, 0.1, (steps + 1, h, w)).astype(np.float32),
        pick=pick.astype(np.float32),
        place=place.astype(np.float32),
        random=random,
        progress=np.linspace(0, 1, steps + 1).astype(np.float32),
        blocks=rng.uniform(0, 0.1, (steps + 1, n, 4)).astype(np.float32),
        targets=rng.uniform(0, 0.1, (n, 4)).astype(np.float32),
        attrs={"n_blocks": n, "primitives": ["ok"] * steps},
    )
