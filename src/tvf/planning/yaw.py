"""Block yaws read from a height map: a place's turn refined below the GCTN's rotation bins.

The `lite` GCTN turns a block in 10° bins, and a block counts as placed only within 15° of its
target's yaw, so a choice a bin or two off (15-18° seen on validation seeds) fails a whole episode. In
this block world yaws (modulo the cube's 90° symmetry) can be read from the top-down height map:

* the picked block's (:func:`face_yaw`): its top face is the connected region within
  :data:`TOP_TOLERANCE` of the height at the pick, and its yaw is the turn of the 4 cm square that
  overlaps it best (a loose block stands alone);
* the goal's at the place (:func:`structure_yaw`): a structure's blocks share one yaw (the task table's
  targets have none of their own), but in the fused goal image neighbouring blocks merge (the cameras
  do not see into 1 cm gaps), so the yaw is the dominant direction of the height edges around the
  place, read as four times the gradient angle.

The turn that brings the one to the other is :func:`refined_turn`; it replaces the GCTN's turn whenever
both readings are clear (modulo the cube's quarter turn, so by at most 45°); where a reading is unclear
the GCTN's turn stays. The first version corrected by at most two `lite` bins (20°); a search
was then seen to execute a proposal 40° off, a turn its foresight cannot see (docs/results.md, "Clear
readings set the turn"). Yaws are world yaws, which in (col, row) pixel coordinates are image
angles (tvf.geometry).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from tvf.geometry import PIXEL_SIZE, wrap_symmetric
from tvf.tasks import BLOCK_SIZE, BLOCK_SYMMETRY

TOP_TOLERANCE = 0.005
"""Metres: pixels this close to the height at the pixel belong to its top face."""
WINDOW = 31
"""Pixels: the square searched around the pixel (a 4 cm block is about 13 px across)."""
MIN_FIT = 0.75
"""Intersection over union of the face with its best square below which its yaw is not trusted (a
face partly hidden or merged with a neighbour)."""
MIN_AGREEMENT = 0.3
"""How alike the edge directions around a goal place must be (the length of their mean over four times
the angle, 1 for one direction) for their yaw to be trusted."""
EDGE_WINDOW = 41
"""Pixels: the square of the goal whose edges give the structure's yaw (about two 5 cm cells around)."""
BLUR_REACH = 4
"""Pixels a one-pixel Gaussian blur reaches (scipy truncates it at 4 sigma)."""
MIN_EDGE = 0.005
"""Metres per pixel (after a one-pixel Gaussian blur): the height gradients counted as edges."""
ANGLES = np.radians(np.arange(-45.0, 45.0, 0.5))
"""Candidate yaws of a face, over one symmetry period."""
PLATEAU = 0.01
"""Candidates whose fit is within this of the best count as equally good."""
PERIODS = round(2 * math.pi / BLOCK_SYMMETRY)
"""Symmetry periods in a full turn (4 for a cube)."""


def top_face(height: np.ndarray, pixel: np.ndarray, window: int = WINDOW) -> np.ndarray:
    """(col, row) coordinates (N, 2) of the top face's pixels around ``pixel`` (row, col): the connected
    region within :data:`TOP_TOLERANCE` of the height at ``pixel``, inside a ``window`` square."""
    r, c = int(pixel[0]), int(pixel[1])
    half = window // 2
    r0, c0 = max(r - half, 0), max(c - half, 0)
    patch = height[r0 : r + half + 1, c0 : c + half + 1]
    near = np.abs(patch - height[r, c]) <= TOP_TOLERANCE
    labels, _ = ndimage.label(near)
    rows, cols = np.nonzero(labels == labels[r - r0, c - c0])
    return np.stack([cols + c0, rows + r0], axis=1).astype(np.float64)


def face_yaw(height: np.ndarray, pixel: np.ndarray) -> tuple[float, float]:
    """The yaw in [-45°, 45°) of the block face at ``pixel`` and how well a 4 cm square fits it (IoU)."""
    face = top_face(height, pixel)
    centre = face.mean(axis=0)
    half = BLOCK_SIZE / PIXEL_SIZE / 2
    lo, hi = np.floor(face.min(axis=0) - half), np.ceil(face.max(axis=0) + half)
    cols, rows = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
    grid = np.stack([cols.ravel(), rows.ravel()], axis=1) - centre
    on_face = np.zeros(len(grid), bool)
    offsets = (face - lo).astype(int)
    on_face[offsets[:, 1] * cols.shape[1] + offsets[:, 0]] = True
    cos, sin = np.cos(ANGLES)[:, None], np.sin(ANGLES)[:, None]
    u = cos * grid[:, 0] + sin * grid[:, 1]  # the grid turned by -angle
    v = -sin * grid[:, 0] + cos * grid[:, 1]
    in_square = (np.abs(u) <= half) & (np.abs(v) <= half)
    overlap = (in_square & on_face).sum(axis=1)
    iou = overlap / (in_square.sum(axis=1) + on_face.sum() - overlap)
    best = iou.max()
    # squares a few degrees apart cover the same pixel centres: the middle of the best ones, averaged
    # over the symmetry period (4 x the angle) so that -44° and 44° meet
    turns = PERIODS * ANGLES[iou >= best - PLATEAU]
    middle = math.atan2(np.sin(turns).mean(), np.cos(turns).mean()) / PERIODS
    return float(wrap_symmetric(middle, BLOCK_SYMMETRY)), float(best)


def structure_yaw(height: np.ndarray, pixel: np.ndarray, window: int = EDGE_WINDOW) -> tuple[float, float]:
    """The yaw in [-45°, 45°) of the height edges in a ``window`` square around ``pixel`` and how alike
    their directions are (0..1): the gradient-weighted mean of four times their angles."""
    r, c = int(pixel[0]), int(pixel[1])
    half = window // 2
    # blur only the window and the blur's reach around it (4 px at sigma 1): the same values there
    lo, hi = (max(r - half, 0), max(c - half, 0)), (r + half + 1, c + half + 1)
    outer = tuple(slice(max(a - BLUR_REACH, 0), b + BLUR_REACH) for a, b in zip(lo, hi, strict=True))
    smooth = ndimage.gaussian_filter(height[outer].astype(np.float64), 1.0)
    inner = tuple(slice(a - o.start, b - o.start) for a, b, o in zip(lo, hi, outer, strict=True))
    patch = smooth[inner]
    gy, gx = ndimage.sobel(patch, axis=0) / 8, ndimage.sobel(patch, axis=1) / 8  # metres per pixel
    strength = np.hypot(gx, gy)
    edges = strength > MIN_EDGE
    if not edges.any():
        return 0.0, 0.0
    mean = (strength[edges] * np.exp(1j * PERIODS * np.arctan2(gy[edges], gx[edges]))).sum()
    mean /= strength[edges].sum()
    return float(wrap_symmetric(np.angle(mean) / PERIODS, BLOCK_SYMMETRY)), float(abs(mean))


def refined_turn(
    turn: float, height: np.ndarray, pick: np.ndarray, goal_height: np.ndarray, place: np.ndarray
) -> float:
    """The GCTN's ``turn`` (radians) corrected to bring the block at ``pick`` (in ``height``) to the yaw
    of the goal's structure at ``place`` (in ``goal_height``); ``turn`` itself where the block's face is
    not clearly a square or the goal's edges do not agree on a direction."""
    block, fit = face_yaw(height, pick)
    target, agreement = structure_yaw(goal_height, place)
    if fit < MIN_FIT or agreement < MIN_AGREEMENT:
        return turn
    return turn + float(wrap_symmetric(target - block - turn, BLOCK_SYMMETRY))
