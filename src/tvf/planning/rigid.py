"""A foresight without a network: the picked block moved as a rigid body (``--foresight rigid``).

The `lite` VF foresees the expert's moves within 2-3 mm but the GCTN's own moves on the unseen tasks
a block off, and its blurred surfaces are too soft for the support check to read (docs/results.md, "The
VF on the planner's own moves", "A support check on the places"). This world's blocks are rigid cubes,
so one step of foresight can also be drawn from the height map alone:

1. the picked block is the set of pixels joined to the pick pixel at its height (within
   :data:`SAME_SURFACE`), no further than :data:`REACH` pixels from it; a pick on nothing a block tall
   (the table, a base cell) moves nothing, as the suction lifts nothing;
2. where it stood the surface drops by one block, coloured as the level it shows: the table, a base
   cell or another block (each colour read from the same image);
3. its pixels turn by the place yaw about the pick and move to the place (the transform of the VF's
   place mask, :func:`tvf.models.vf.moved_to_place`) and land on the highest surface under them.

By default falls are not drawn: a block put half over its support lands flat at the support's level
(``PlannerConfig.support_check``, :mod:`tvf.planning.support`, ranks such children lower; with this
foresight it cost TVF-L episodes on validation seeds). Without the image rules TVF-L with it finished
80.0 % of the unseen test episodes against 65.6 % with the `lite` VF (docs/results.md, "A foresight
without a network"). With ``falls=True`` (``--foresight rigid-falls``) a landed block whose centre is not
inside the support under it (the rule of :mod:`tvf.planning.support`, read on its own moved footprint)
tips away from that support: it moves :data:`FALL_STEP` pixels at a time, at most :data:`FALL_STEPS`
times, until it rests, and lands there. An option and a deviation from the paper's learned VF
(docs/deviations.md P22).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from tvf.models.images import HEIGHT_CHANNEL, ArrayLike, as_pixels, clamp_rgbh, heights_of, normalised_heights
from tvf.models.vf import moved_to_place
from tvf.planning.support import DIRECTION_VECTORS, LIFT_RADIUS, held_all_round
from tvf.tasks import BLOCK_SIZE, CELL_THICKNESS

SAME_SURFACE = 0.01
"""Metres: pixels joined to the pick within this of its height belong to the picked block's top."""
REACH = 2 * LIFT_RADIUS
"""Pixels: the picked block's pixels lie within this of the pick (a pick at one corner of a block
turned 45 degrees still reaches the opposite one)."""
FILL_STEPS = int(REACH) + 2
"""Growth steps of the flood fill from the pick pixel: enough to cross :data:`REACH`."""
LIFTABLE = BLOCK_SIZE / 2
"""Metres: a pick lower than this lifts nothing (the table, a base cell's top)."""
TABLE_LEVEL = CELL_THICKNESS / 2
"""Metres: an uncovered surface lower than this is the table; up to :data:`LIFTABLE` a base cell, above
it another block."""
FALL_STEP = 4
"""Pixels a block that would not rest moves per step away from its support (an eighth of a block's 13)."""
FALL_STEPS = 4
"""Steps a falling block may take (16 px, past the edge of any support it was put half over)."""


RIGID_FORESIGHTS = {"rigid": False, "rigid-falls": True}
"""The ``--foresight`` names of this module, and whether each draws falls."""


def rigid_foresight(name: str) -> RigidForesight:
    """The rigid foresight ``--foresight NAME`` names (a key of :data:`RIGID_FORESIGHTS`)."""
    return RigidForesight(falls=RIGID_FORESIGHTS[name])


def picked_block(heights: torch.Tensor, picks: torch.Tensor) -> torch.Tensor:
    """(B, H, W) bool: the pixels of the block picked at ``picks`` (B, 2 rows, cols) on ``heights``
    (B, H, W metres); empty where the pick is lower than :data:`LIFTABLE`."""
    b, h, w = heights.shape
    index = torch.arange(b, device=heights.device)
    top = heights[index, picks[:, 0], picks[:, 1]]
    rows = torch.arange(h, device=heights.device)[None, :, None] - picks[:, 0, None, None]
    cols = torch.arange(w, device=heights.device)[None, None, :] - picks[:, 1, None, None]
    allowed = ((heights - top[:, None, None]).abs() <= SAME_SURFACE) & (rows**2 + cols**2 <= REACH**2)
    allowed &= (top >= LIFTABLE)[:, None, None]
    grown = torch.zeros_like(heights)
    grown[index, picks[:, 0], picks[:, 1]] = 1.0
    grown = grown * allowed
    for _ in range(FILL_STEPS):
        grown = F.max_pool2d(grown[:, None], 3, stride=1, padding=1)[:, 0] * allowed
    return grown > 0.5


def _mean_colour(
    colours: torch.Tensor, where: torch.Tensor, fallback: torch.Tensor | None = None
) -> torch.Tensor:
    """(B, 3) mean colour of the pixels ``where`` (B, H, W) of ``colours`` (B, 3, H, W); ``fallback``
    (B, 3) where an image has none."""
    weights = where.to(colours)[:, None]
    count = weights.sum(dim=(-2, -1))
    mean = (colours * weights).sum(dim=(-2, -1)) / count.clamp(min=1)
    return mean if fallback is None else torch.where(count > 0, mean, fallback)


def uncovered_colours(
    colours: torch.Tensor, heights: torch.Tensor, block: torch.Tensor, lowered: torch.Tensor
) -> torch.Tensor:
    """(B, 3, H, W) the colour each pixel would show at the heights ``lowered`` (B, H, W): the table, base
    cell or block colour (normalised) of the scene ``colours`` (B, 3, H, W), ``heights`` (B, H, W) whose
    picked block's pixels are ``block`` (B, H, W; its colour is the blocks')."""
    table = _mean_colour(colours, heights < TABLE_LEVEL / 2)
    cell = _mean_colour(colours, (heights - CELL_THICKNESS).abs() < TABLE_LEVEL / 2, table)
    red = _mean_colour(colours, block, table)
    level = torch.where(lowered < TABLE_LEVEL, 0, torch.where(lowered < LIFTABLE, 1, 2))
    palette = torch.stack([table, cell, red], dim=1)  # (B, 3 levels, 3 channels)
    shown = torch.gather(palette, 1, level.flatten(1)[:, :, None].expand(-1, -1, 3))
    return shown.transpose(1, 2).reshape(colours.shape)


def landing(footprint: torch.Tensor, surface: torch.Tensor) -> torch.Tensor:
    """(B,) the highest height of ``surface`` (B, H, W metres) under each ``footprint`` (B, H, W bool); 0
    where a footprint is empty."""
    return torch.where(footprint, surface, torch.zeros_like(surface)).amax(dim=(-2, -1))


def _pixel_grid(shape: tuple[int, int], device: torch.device) -> torch.Tensor:
    """(H * W, 2) float (row, col) of every pixel, row by row."""
    rows, cols = torch.meshgrid(
        torch.arange(shape[0], device=device), torch.arange(shape[1], device=device), indexing="ij"
    )
    return torch.stack([rows.flatten(), cols.flatten()], dim=-1).float()


def _centroid(where: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """(B, 2) mean (row, col) of the pixels ``where`` (B, H * W) of ``grid``; (0, 0) where none."""
    weights = where.float()
    return weights @ grid / weights.sum(dim=1).clamp(min=1)[:, None]


def resting(footprint: torch.Tensor, surface: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Whether a block with ``footprint`` (B, H, W bool) landed on ``surface`` (B, H, W metres) rests, by
    the support check's rule (:func:`tvf.planning.support.held_all_round`) read on the block's own
    footprint. Returns (B,) bool (True for an empty footprint) and (B, 2) the unit (row, col) direction
    from the support's centroid to the block's centre, the way it would tip (0 where it rests)."""
    grid = _pixel_grid(tuple(surface.shape[-2:]), surface.device)
    inside = footprint.flatten(1)
    under = torch.where(inside, surface.flatten(1), torch.tensor(-math.inf).to(surface))
    centre = _centroid(inside, grid)
    directions = DIRECTION_VECTORS.to(surface)
    rests, holds = held_all_round(under, (grid @ directions)[None] - (centre @ directions)[:, None])
    rests |= ~inside.any(dim=1)
    away = centre - _centroid(holds & inside, grid)
    away = away / away.norm(dim=1, keepdim=True).clamp(min=1e-6)
    return rests, torch.where(rests[:, None], torch.zeros_like(away), away)


class RigidForesight(nn.Module):
    """The next image after a pick-and-place as a rigid move of the picked block (the module docstring);
    the VF's :meth:`predict_rgbh` interface, so :class:`~tvf.planning.search.TreeSearch` takes it as its
    foresight. No parameters; batched over the images. ``falls`` True lets a block that would not rest
    tip off its support (``--foresight rigid-falls``)."""

    def __init__(self, falls: bool = False) -> None:
        super().__init__()
        self.falls = falls

    @torch.no_grad()
    def predict_rgbh(
        self, rgbh: torch.Tensor, pick_pixels: ArrayLike, place_pixels: ArrayLike, yaws: ArrayLike
    ) -> torch.Tensor:
        """Normalised RGB-H (B, 4, H, W), pick and place pixels (B, 2 rows, cols), place yaw changes (B,)
        in radians (world yaw, geometry's convention) -> the imagined next images (B, 4, H, W)."""
        if rgbh.dim() != 4 or rgbh.shape[1] != HEIGHT_CHANNEL + 1:
            raise ValueError(f"normalised RGB-H (B, 4, H, W) expected, got {tuple(rgbh.shape)}")
        b, _, h, w = rgbh.shape
        picks = as_pixels(pick_pixels, b, (h, w)).to(rgbh.device)
        places = as_pixels(place_pixels, b, (h, w)).to(rgbh.device)
        heights = heights_of(rgbh)
        block = picked_block(heights, picks)
        # the block leaves: its pixels drop by one block and show the level beneath
        lowered = torch.where(block, (heights - BLOCK_SIZE).clamp(min=0.0), heights)
        below = uncovered_colours(rgbh[:, :HEIGHT_CHANNEL], heights, block, lowered)
        colours = torch.where(block[:, None], below, rgbh[:, :HEIGHT_CHANNEL])
        # its pixels move as the VF's place mask does and land on the highest surface under them
        carried = torch.cat([rgbh[:, :HEIGHT_CHANNEL], block[:, None].to(rgbh)], dim=1)
        turns = torch.as_tensor(yaws, dtype=torch.float32).reshape(b)
        moved = moved_to_place(carried, picks, places, turns)
        if self.falls:
            moved = self._tipped(moved, carried, lowered, picks, places, turns)
        footprint = moved[:, HEIGHT_CHANNEL] > 0.5
        landed = torch.where(footprint, landing(footprint, lowered)[:, None, None] + BLOCK_SIZE, lowered)
        colours = torch.where(footprint[:, None], moved[:, :HEIGHT_CHANNEL], colours)
        return clamp_rgbh(torch.cat([colours, normalised_heights(landed)[:, None]], dim=1))

    @staticmethod
    def _tipped(moved: torch.Tensor, carried: torch.Tensor, surface: torch.Tensor, picks: torch.Tensor,
                places: torch.Tensor, turns: torch.Tensor) -> torch.Tensor:  # fmt: skip
        """``moved`` (B, 4, H, W: colours and the block's mask at the place) with every block that would
        not rest on ``surface`` moved :data:`FALL_STEP` pixels away from its support until it rests, at
        most :data:`FALL_STEPS` times; ``carried`` is the content before the move."""
        h, w = surface.shape[-2:]
        offset = torch.zeros(len(places), 2, device=places.device)
        for _ in range(FALL_STEPS):
            rests, away = resting(moved[:, HEIGHT_CHANNEL] > 0.5, surface)
            if bool(rests.all()):
                break
            offset = offset + FALL_STEP * away
            shifted = places + offset.round().long()
            shifted = torch.stack([shifted[:, 0].clamp(0, h - 1), shifted[:, 1].clamp(0, w - 1)], dim=1)
            moved = torch.where(
                rests[:, None, None, None], moved, moved_to_place(carried, picks, shifted, turns)
            )
        return moved
