"""Imagined heights snapped to the levels things rest at in this world.

Every surface of a scene at rest lies at one of a few heights: the table (0), a base cell's top
(``CELL_THICKNESS``), and the top of a stack of k blocks on the table (k * ``BLOCK_SIZE``) or on a cell
(``CELL_THICKNESS`` + k * ``BLOCK_SIZE``). A VF's imagined heights lie between them where it is unsure
(a blurred edge, a block half on a tower), and fed its own output the search drifts further at every
level. :func:`snap_heights` sets every pixel the VF moved to the nearest level, so the next level starts
from a scene that could exist and a node's distance to the goal counts blocks, not blur
(``PlannerConfig.snap_heights``, an option). Only height is snapped: colour is left as the VF drew it.
It cuts the VF's three-step height error on the expert's moves (unseen tasks 2.56 -> 1.50 mm) but did
not lift what TVF-L finishes (docs/results.md, "Imagined heights snapped to the resting levels").
"""

from __future__ import annotations

import torch

from tvf.models.images import HEIGHT_CHANNEL, MAX_HEIGHT, heights_of, normalised_heights
from tvf.tasks import BLOCK_SIZE, CELL_THICKNESS

SNAP_TOLERANCE = 0.02
"""Metres: a moved pixel further than this from every level keeps the VF's height (half a block: every
moved pixel is snapped, as no two levels lie more than a block apart)."""
MOVED = 0.001
"""Metres: pixels whose imagined height differs from the parent's by more are snapped; the others keep
the VF's height (within this of the parent's, so an untouched real surface is not moved to a level)."""


def resting_levels(max_height: float = MAX_HEIGHT) -> torch.Tensor:
    """The heights (metres, ascending) a surface at rest can have, up to ``max_height``."""
    stacks = int(max_height // BLOCK_SIZE)
    tops = [k * BLOCK_SIZE + base for k in range(stacks + 1) for base in (0.0, CELL_THICKNESS)]
    return torch.tensor(sorted(h for h in tops if h <= max_height), dtype=torch.float64)


RESTING_LEVELS = resting_levels()
"""The levels of the whole workspace (:data:`MAX_HEIGHT`), built once for :func:`snap_heights`."""


def nearest_level(heights: torch.Tensor, levels: torch.Tensor) -> torch.Tensor:
    """Each height (any shape, metres) replaced by the nearest of ``levels`` (ascending, 1-D)."""
    levels = levels.to(heights)
    upper = torch.bucketize(heights, levels).clamp(1, len(levels) - 1)
    below, above = levels[upper - 1], levels[upper]
    return torch.where(heights - below <= above - heights, below, above)


def snap_heights(
    images: torch.Tensor, parents: torch.Tensor, tolerance: float = SNAP_TOLERANCE, moved: float = MOVED
) -> torch.Tensor:
    """``images`` (normalised RGB-H, (B, 4, H, W), imagined from ``parents`` of the same shape) with every
    pixel whose height moved by more than ``moved`` metres set to the nearest resting level when it lies
    within ``tolerance`` of it. A new tensor; colour is unchanged."""
    if images.shape != parents.shape:
        raise ValueError(f"images {tuple(images.shape)} and parents {tuple(parents.shape)} differ in shape")
    heights = heights_of(images)
    level = nearest_level(heights, RESTING_LEVELS)
    snap = ((heights - heights_of(parents)).abs() > moved) & ((heights - level).abs() <= tolerance)
    out = images.clone()
    out[:, HEIGHT_CHANNEL] = torch.where(snap, normalised_heights(level), images[:, HEIGHT_CHANNEL])
    return out
