"""The one success rule, used by the environment, the oracle, evaluation and data generation.

A structure is finished when every block can be matched one-to-one to a target with an xy error below
1 cm, a z error below 5 mm and a yaw error below 15 degrees modulo the block's 90 degree symmetry.
The matching is a maximum bipartite matching, so the result never depends on block order.
:func:`target_misses` says how each target left unfilled is missed (the episode records' ``misses``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from tvf.geometry import wrap_symmetric
from tvf.tasks import BLOCK_SYMMETRY, CELL_SIZE


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


MISS_KINDS = ("turn", "offset", "level", "away")
"""How :func:`target_misses` names a miss by the block nearest the target: ``turn`` (at its place and
level, turned 15 degrees or more), ``offset`` (at its level, 1 cm or more but under half a cell off),
``level`` (under half a cell off, at another height: a block on a neighbour, a fallen one) and ``away``
(no unmatched block within half a cell, or none left)."""
NEAR = CELL_SIZE / 2
"""Metres: a block within this of a target (xy) sits on its cell."""


def miss_kind(xy: float, dz: float, tol: Tolerance = TOLERANCE) -> str:
    """The :data:`MISS_KINDS` entry of a block ``xy`` metres from a target and ``dz`` above it."""
    if xy >= NEAR:
        return "away"
    if abs(dz) >= tol.z:
        return "level"
    return "turn" if xy < tol.xy else "offset"


def target_misses(
    block_pos: np.ndarray, block_yaw: np.ndarray, target_pos: np.ndarray, target_yaw: np.ndarray,
    block_to_target: tuple[int, ...], tol: Tolerance = TOLERANCE,
) -> list[dict]:  # fmt: skip
    """One record per target the matching ``block_to_target`` (:attr:`Progress.block_to_target`) leaves
    unfilled, in target order: the target's index and the errors of the unmatched block paired with it
    (the pairing of unmatched blocks and targets nearest in xy overall): ``xy_mm``, ``z_mm`` (block
    above target), ``yaw_deg`` (modulo the block's symmetry) and ``kind`` (:func:`miss_kind`). With no
    unmatched block left for it the errors are None and the kind ``away``."""
    taken = {t for t in block_to_target if t >= 0}
    targets = [j for j in range(len(target_pos)) if j not in taken]
    blocks = [i for i, t in enumerate(block_to_target) if t < 0]
    if not targets:
        return []
    bp, tp = np.asarray(block_pos), np.asarray(target_pos)
    pairs: dict[int, int] = {}
    if blocks:
        xy = np.linalg.norm(bp[blocks][:, None, :2] - tp[targets][None, :, :2], axis=-1)
        rows, cols = linear_sum_assignment(xy)
        pairs = {targets[c]: blocks[r] for r, c in zip(rows, cols, strict=True)}
    out = []
    for j in targets:
        if j not in pairs:
            out.append({"target": j, "xy_mm": None, "z_mm": None, "yaw_deg": None, "kind": "away"})
            continue
        i = pairs[j]
        xy = float(np.linalg.norm(bp[i, :2] - tp[j, :2]))
        dz = float(bp[i, 2] - tp[j, 2])
        yaw = abs(float(wrap_symmetric(np.asarray(block_yaw)[i] - np.asarray(target_yaw)[j], BLOCK_SYMMETRY)))
        out.append({"target": j, "xy_mm": round(xy * 1000, 1), "z_mm": round(dz * 1000, 1),
                    "yaw_deg": round(math.degrees(yaw), 1), "kind": miss_kind(xy, dz, tol)})  # fmt: skip
    return out
