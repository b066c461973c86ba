"""The scripted expert: which block next, where to pick it, and the place pose that lands it on target.

An action is a ``(2, 4)`` array: the pick pose and the place pose, each (x, y, z, yaw) in the world
frame. The tool moves rigidly from pick to place, so the picked block turns by ``place_yaw - pick_yaw``
about the pick point. The oracle always picks with yaw 0.
"""

from __future__ import annotations

import numpy as np
import pybullet as p

from tvf.geometry import PIXEL_SIZE, WORKSPACE, rotate_xy, wrap_angle, wrap_symmetric
from tvf.sim.success import evaluate_structure
from tvf.sim.world import BLOCK_RADIUS, CELL_RADIUS, World, layout_cell_centres, sample_free_pose
from tvf.tasks import BLOCK_SIZE, BLOCK_SYMMETRY

PICK_INSET = 0.008
"""The oracle picks within the block's top face shrunk by this much (m) on each side."""
RAY_TOP = 0.2
"""Visibility rays start here: above any structure, below the arm's travel height."""
NEAR_MISS_OFFSET = 8 * PIXEL_SIZE
"""A near miss moves the expert's place by up to this much (m): 8 pixels, 2.5 cm, a little more than a
block's half-width, so its outcomes range from landing right to sliding off or toppling a tower."""
NEAR_MISS_TURN = np.deg2rad(10.0)
"""... and turns it by up to this much (one of the paper's 36 rotation bins)."""


def make_action(pick_xyz, pick_yaw: float, place_xyz, place_yaw: float) -> np.ndarray:
    return np.array([[*pick_xyz, pick_yaw], [*place_xyz, place_yaw]], dtype=np.float64)


def _pick_point(world: World, block: int, rng: np.random.Generator) -> np.ndarray | None:
    """A random point on the block's top face that is visible from above, or None if it is covered."""
    pos, yaw = world.block_poses()
    half = BLOCK_SIZE / 2 - PICK_INSET
    for _ in range(8):
        local = rng.uniform(-half, half, size=2)
        xy = pos[block, :2] + rotate_xy(local, yaw[block])
        hit = p.rayTest([*xy, RAY_TOP], [*xy, 0.0], physicsClientId=world.client)[0]
        if hit[0] == world.blocks[block]:
            return np.array([xy[0], xy[1], hit[3][2]])
    return None


def _loose_blocks_by_distance(world: World, targets: list[int]) -> list[tuple[int, int]]:
    """Unmatched blocks paired with their nearest given target, farthest pair first (as the reference)."""
    pos, yaw = world.block_poses()
    tpos, tyaw = world.target_poses()
    progress = evaluate_structure(pos, yaw, tpos, tyaw)
    loose = [i for i, t in enumerate(progress.block_to_target) if t < 0]
    pairs = []
    for i in loose:
        d = np.linalg.norm(tpos[targets] - pos[i], axis=1)
        pairs.append((float(d.min()), i, targets[int(d.argmin())]))
    pairs.sort(key=lambda x: -x[0])
    return [(i, t) for _, i, t in pairs]


def ready_targets(world: World, order: tuple[tuple[int, ...], ...]) -> list[int]:
    """Unfilled targets of the current subgoal group whose supports are filled."""
    assert world.task is not None
    pos, yaw = world.block_poses()
    tpos, tyaw = world.target_poses()
    filled = set(t for t in evaluate_structure(pos, yaw, tpos, tyaw).block_to_target if t >= 0)
    supports = world.task.supports()
    for group in order:
        open_ = [t for t in group if t not in filled]
        if open_:
            return [t for t in open_ if all(s in filled for s in supports[t])]
    return []


def oracle_action(
    world: World, order: tuple[tuple[int, ...], ...], rng: np.random.Generator, first: int | None = None
) -> np.ndarray | None:
    """The expert's next action, or None when the structure is finished or nothing can be picked.

    ``first``: move this block first if it is loose (the repair of a near miss, which the farthest-first
    rule would leave where it fell, sometimes on the spot of its own target)."""
    targets = ready_targets(world, order)
    if not targets:
        return None
    pos, yaw = world.block_poses()
    tpos, tyaw = world.target_poses()
    pairs = sorted(_loose_blocks_by_distance(world, targets), key=lambda pair: pair[0] != first)
    for block, target in pairs:
        pick = _pick_point(world, block, rng)
        if pick is None:
            continue
        delta = float(wrap_symmetric(tyaw[target] - yaw[block], BLOCK_SYMMETRY))
        place_xy = tpos[target, :2] + rotate_xy(pick[:2] - pos[block, :2], delta)
        place_z = tpos[target, 2] + (pick[2] - pos[block, 2])
        return make_action(pick, 0.0, (*place_xy, place_z), delta)
    return None


def random_action(
    world: World, order: tuple[tuple[int, ...], ...], rng: np.random.Generator
) -> np.ndarray | None:
    """Move the block the oracle would move next to a random free spot with a random yaw."""
    assert world.task is not None and world.layout is not None
    targets = ready_targets(world, order)
    if not targets:
        return None
    pos, yaw = world.block_poses()
    for block, _ in _loose_blocks_by_distance(world, targets):
        pick = _pick_point(world, block, rng)
        if pick is None:
            continue
        cells = layout_cell_centres(world.task, world.layout)
        occupied = [(c, CELL_RADIUS) for c in cells]
        occupied += [(pos[i, :2], BLOCK_RADIUS) for i in range(len(pos)) if i != block]
        xy, new_yaw = sample_free_pose(rng, occupied, world.config.scene, world.workspace)
        if xy is None:
            return None
        delta = float(wrap_angle(new_yaw - yaw[block]))
        place_xy = xy + rotate_xy(pick[:2] - pos[block, :2], delta)
        place_z = BLOCK_SIZE / 2 + (pick[2] - pos[block, 2])
        return make_action(pick, 0.0, (*place_xy, place_z), delta)
    return None


def near_miss(action: np.ndarray, rng: np.random.Generator, max_offset: float = NEAR_MISS_OFFSET,
              max_turn: float = NEAR_MISS_TURN) -> np.ndarray:  # fmt: skip
    """The expert's ``action`` placed a little off, as a learned policy a few pixels wrong places it.

    The place is moved by an offset drawn uniformly from the disc of radius ``max_offset`` (kept a block
    inside the workspace) and its yaw turned by up to ``max_turn``; the pick is the expert's. Executed,
    its outcomes (the block lands right, slides, topples or knocks another) are the foresight's data for
    the GCTN's near-duplicate places (``tvf demos --near-misses``)."""
    out = np.array(action, dtype=np.float64, copy=True)
    radius, angle = max_offset * np.sqrt(rng.uniform()), rng.uniform(0.0, 2 * np.pi)
    x = out[1, 0] + radius * np.cos(angle)
    y = out[1, 1] + radius * np.sin(angle)
    margin = BLOCK_SIZE  # the block stays pickable (its centre in the workspace) after it slides
    out[1, 0] = np.clip(x, WORKSPACE.x_min + margin, WORKSPACE.x_max - margin)
    out[1, 1] = np.clip(y, WORKSPACE.y_min + margin, WORKSPACE.y_max - margin)
    out[1, 3] = wrap_angle(out[1, 3] + rng.uniform(-max_turn, max_turn))
    return out


def random_schedule(n_steps: int, n_random: int, rng: np.random.Generator) -> list[bool]:
    """Which of ``n_steps`` steps are random: exactly ``n_random``, never two in a row, never the last.

    Follows the reference's rule (facts §4): a random step is forced when the remaining steps
    demand it, otherwise a fair coin decides, and a random step is never followed by another.
    """
    if n_random and n_steps < 2 * n_random:
        raise ValueError(f"cannot fit {n_random} non-consecutive random steps before the last of {n_steps}")
    out: list[bool] = []
    done = 0
    for step in range(n_steps):
        if done == n_random or step == n_steps - 1 or (out and out[-1]):
            choice = False
        elif n_steps - 1 - step <= 2 * (n_random - done) - 1:
            choice = True
        else:
            choice = bool(rng.random() < 0.5)
        done += choice
        out.append(choice)
    return out
