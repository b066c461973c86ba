"""The one success rule, used by the environment, the oracle, evaluation and data generation.

A structure is finished when every block can be matched one-to-one to a target with an xy error below
1 cm, a z error below 5 mm and a yaw error below 15 degrees modulo the block's 90 degree symmetry.
The matching is a maximum bipartite matching, so the result never depends on block order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from tvf.geometry import wrap_symmetric
from tvf.tasks import BLOCK_SYMMETRY


@dataclass(frozen=True)
class Tolerance:
    xy: float = 0.01
    z: float = 0.005
    yaw: float = math.radians(15.0)


TOLERANCE = Tolerance()


def pose_matches(
    block_pos: np.ndarray, block_yaw: np.ndarray, target_pos: np.ndarray, target_yaw: np.ndarray,
    tol: Tolerance = TOLERANCE,
) -> np.ndarray:  # fmt: skip
    """Boolean matrix ``(n_blocks, n_targets)``: block i is within tolerance of target j."""
    bp, tp = np.asarray(block_pos)[:, None, :], np.asarray(target_pos)[None, :, :]
    xy_ok = np.linalg.norm(bp[..., :2] - tp[..., :2], axis=-1) < tol.xy
    z_ok = np.abs(bp[..., 2] - tp[..., 2]) < tol.z
    dyaw = np.abs(
        wrap_symmetric(np.asarray(block_yaw)[:, None] - np.asarray(target_yaw)[None, :], BLOCK_SYMMETRY)
    )
    return xy_ok & z_ok & (dyaw < tol.yaw)


def match_targets(ok: np.ndarray) -> np.ndarray:
    """A maximum one-to-one matching; returns the target index per block (-1 if unmatched)."""
    n_blocks, n_targets = ok.shape
    out = np.full(n_blocks, -1, dtype=np.int64)
    if ok.size == 0 or not ok.any():
        return out
    rows, cols = linear_sum_assignment(~ok)  # cost 0 for a feasible pair, 1 otherwise
    for r, c in zip(rows, cols, strict=True):
        if ok[r, c]:
            out[r] = c
    return out


@dataclass(frozen=True)
class Progress:
    matched: int
    n_targets: int
    block_to_target: tuple[int, ...]

    @property
    def fraction(self) -> float:
        return self.matched / self.n_targets if self.n_targets else 1.0

    @property
    def success(self) -> bool:
        return self.matched == self.n_targets


def evaluate_structure(
    block_pos: np.ndarray, block_yaw: np.ndarray, target_pos: np.ndarray, target_yaw: np.ndarray,
    tol: Tolerance = TOLERANCE,
) -> Progress:  # fmt: skip
    """Success and progress (fraction of targets matched) of a scene."""
    assignment = match_targets(pose_matches(block_pos, block_yaw, target_pos, target_yaw, tol))
    return Progress(int((assignment >= 0).sum()), len(target_pos), tuple(int(a) for a in assignment))
