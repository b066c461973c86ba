"""Whether a placed block would rest where the search imagines it: a support check on the height map.

The VF draws a placed block where it is put. In this world a block whose centre is not over what it
lands on slides off or topples, and on the unseen tasks most of the planner's own moves that the VF
gets wrong are such moves (docs/results.md, "The VF on the planner's own moves"). :func:`rests` reads
the parent scene's height map under the place: the block lands on the highest surface under its
footprint (the inscribed disc of the 4 cm block, so any turn), the pixels within
:data:`SUPPORT_TOLERANCE` of that level hold it, and it rests when its centre lies strictly inside
their hull (support on every side of it, :data:`SUPPORT_MARGIN` pixels past it, in each of
:data:`DIRECTIONS` directions). The picked block leaves first: the disc that holds its footprint at any
turn (:data:`LIFT_RADIUS`) is lowered by one block. With ``PlannerConfig.support_check`` a child
that fails it, and everything below it, ranks under every node that rests (:data:`FALL_PENALTY`; an
option: the paper's search has no such check).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from tvf.geometry import PIXEL_SIZE
from tvf.tasks import BLOCK_SIZE

SUPPORT_TOLERANCE = 0.006
"""Metres: footprint pixels this close below the landing level hold the block."""
SUPPORT_MARGIN = 1.0
"""Pixels: the support must reach this far past the block's centre in every direction."""
DIRECTIONS = 16
"""Directions in which the support must reach past the centre."""
FALL_PENALTY = 1.0
"""Added to the distance D of a node whose path holds a place that would not rest: the whole bonus C
of the score gamma**(d-1) * (C - D), so it ranks under every node that rests (D < C), and the least
distant first where none does."""
FOOTPRINT_RADIUS = BLOCK_SIZE / PIXEL_SIZE / 2
"""Pixels: the radius of the disc inscribed in a block's square footprint (6.4)."""

LIFT_RADIUS = FOOTPRINT_RADIUS * math.sqrt(2)
"""Pixels: the radius of the disc around a block's square footprint at any turn (9.05): the picked
block's pixels, lowered as it leaves (its turn is not read; the edges of a block beside it are lowered
too, which can only make a place look held)."""


def footprint_offsets(radius: float = FOOTPRINT_RADIUS) -> torch.Tensor:
    """(P, 2) integer (row, col) offsets of the pixels of a disc of ``radius`` pixels around a centre."""
    r = int(math.floor(radius))
    rows, cols = np.mgrid[-r : r + 1, -r : r + 1]
    inside = rows**2 + cols**2 <= radius**2
    return torch.as_tensor(np.stack([rows[inside], cols[inside]], axis=1), dtype=torch.long)


OFFSETS = footprint_offsets()
LIFT_OFFSETS = footprint_offsets(LIFT_RADIUS)
_ANGLES = torch.arange(DIRECTIONS, dtype=torch.float32) * (2 * math.pi / DIRECTIONS)
DIRECTION_VECTORS = torch.stack([torch.sin(_ANGLES), torch.cos(_ANGLES)])
"""(2, DIRECTIONS): the unit (row, col) vectors of the directions the support must reach in."""
REACH = OFFSETS.float() @ DIRECTION_VECTORS
"""(P, DIRECTIONS): how far each footprint pixel lies past the centre in each direction (pixels)."""


def _gather(heights: torch.Tensor, centres: torch.Tensor) -> torch.Tensor:
    """(N, P) heights of the footprint pixels around ``centres`` (N, 2); outside the image: the table."""
    pad = OFFSETS.abs().max().item()
    padded = F.pad(heights, (pad, pad, pad, pad))
    offsets = OFFSETS.to(heights.device)
    rows = centres[:, None, 0] + offsets[None, :, 0] + pad
    cols = centres[:, None, 1] + offsets[None, :, 1] + pad
    return padded[torch.arange(len(centres), device=heights.device)[:, None], rows, cols]


def lifted(heights: torch.Tensor, picks: torch.Tensor) -> torch.Tensor:
    """Height maps (N, H, W, metres) with each picked block gone: the disc of :data:`LIFT_RADIUS` pixels
    around its pick lowered by one block."""
    h, w = heights.shape[-2:]
    offsets = LIFT_OFFSETS.to(heights.device)
    rows = (picks[:, None, 0] + offsets[None, :, 0]).clamp(0, h - 1)
    cols = (picks[:, None, 1] + offsets[None, :, 1]).clamp(0, w - 1)
    index = torch.arange(len(picks), device=heights.device)[:, None].expand_as(rows)
    out = heights.clone()
    out[index, rows, cols] = (heights[index, rows, cols] - BLOCK_SIZE).clamp(min=0)
    return out


def held_all_round(under: torch.Tensor, past: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The rule of this module: a block whose P footprint pixels stand on the heights ``under`` (N, P;
    -inf for a pixel outside its footprint) lands on the highest, the pixels within
    :data:`SUPPORT_TOLERANCE` of that level hold it, and it rests when they reach :data:`SUPPORT_MARGIN`
    pixels past its centre in every direction, ``past`` (N or 1, P, DIRECTIONS) saying how far each pixel
    lies past the centre in each. Returns (N,) whether it rests and (N, P) the pixels that hold it."""
    landing = under.max(dim=1, keepdim=True).values
    holds = under >= landing - SUPPORT_TOLERANCE
    reach = torch.where(holds[:, :, None], past, torch.tensor(-math.inf).to(past))
    return (reach.max(dim=1).values >= SUPPORT_MARGIN).all(dim=1), holds


def rests(heights: torch.Tensor, picks: torch.Tensor, places: torch.Tensor) -> torch.Tensor:
    """(N,) bool: the block picked at ``picks`` (N, 2 pixel rows, cols) and put at ``places`` would rest
    there, from the parent scenes' height maps ``heights`` (N, H, W, metres)."""
    if heights.dim() != 3 or picks.shape != places.shape or picks.shape != (heights.shape[0], 2):
        raise ValueError(f"heights (N, H, W) and picks, places (N, 2) expected, got {tuple(heights.shape)}, "
                         f"{tuple(picks.shape)}, {tuple(places.shape)}")  # fmt: skip
    picks, places = picks.long().to(heights.device), places.long().to(heights.device)
    under = _gather(lifted(heights, picks), places)
    return held_all_round(under, REACH.to(under)[None])[0]
