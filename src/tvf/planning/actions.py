"""From image-space decisions (pixels, rotation bins) to world actions the robot executes."""

from __future__ import annotations

import numpy as np

from tvf.geometry import WORKSPACE, bin_to_yaw, pixel_to_world
from tvf.planning.yaw import refined_turn
from tvf.tasks import BLOCK_SIZE

FOOTPRINT_PX = 13
"""A held 4 cm block covers about 13 x 13 pixels; the place height is the highest surface under it."""


def surface_height(height: np.ndarray, pixel: np.ndarray, window: int = FOOTPRINT_PX) -> float:
    """The highest point of the height map in a ``window`` square around ``pixel`` (row, col)."""
    r, c = int(pixel[0]), int(pixel[1])
    h = window // 2
    patch = height[max(r - h, 0) : r + h + 1, max(c - h, 0) : c + h + 1]
    return float(patch.max()) if patch.size else 0.0


def pixels_to_action(pick: np.ndarray, place: np.ndarray, yaw: float, height: np.ndarray) -> np.ndarray:
    """A world action ``(2, 4)`` from a pick pixel, a place pixel, a yaw change and the height map.

    The pick is at the pixel centre at the surface height there (the top of a block); the place puts
    the held block's bottom on the highest surface under its footprint, so the tool tip goes one block
    height above it. The primitive's contact-seeking descent absorbs small height errors.
    """
    pick_xy = pixel_to_world(np.asarray(pick))
    place_xy = pixel_to_world(np.asarray(place))
    pick_z = float(height[int(pick[0]), int(pick[1])])
    place_z = min(surface_height(height, place) + BLOCK_SIZE, WORKSPACE.z_max)
    return np.array([[*pick_xy, pick_z, 0.0], [*place_xy, place_z, float(yaw)]], dtype=np.float64)


def refining_height(goal: dict, refine_yaw: bool) -> np.ndarray | None:
    """The goal's height map where the turn is refined (:func:`bin_action`'s ``goal_height``), else None."""
    return goal["height"] if refine_yaw else None


def bin_action(
    pick: np.ndarray, place: np.ndarray, rot_bin: int, n_rotations: int, height: np.ndarray,
    goal_height: np.ndarray | None = None,
) -> np.ndarray:  # fmt: skip
    """:func:`pixels_to_action` with the yaw change given as a rotation bin; with ``goal_height``, the
    turn refined to the block yaws read from the two height maps (:func:`tvf.planning.yaw.refined_turn`)."""
    turn = float(bin_to_yaw(rot_bin, n_rotations))
    if goal_height is not None:
        turn = refined_turn(turn, height, pick, goal_height, place)
    return pixels_to_action(pick, place, turn, height)
