"""The files round trip of issue 13: plan the first decision of unseen-task episodes inside the simulator
and from its exported files (`tvf render --export-views`: colour PNG, 16-bit depth PNG in mm, camera
files), and count the decisions that agree (the same pick and place pixel and rotation bin).

For TVF methods it also reports how many decisions have the same root proposals on both sides, and the
agreement under each tie band (``PlannerConfig.tie_band``: root actions within the band of the best are
ties, decided by the proposal order) with how many in-simulator decisions the band changes. Where the two
sides disagree (band 0) it says what the difference costs: whether the files' action is physically the
same (pick within 6 px, place within 3 px, rotation within one bin: the GCTN accuracy tolerances), and
how far below the simulator's best the simulator's own search scored the files' action (``score_gaps``;
None where the simulator's search did not propose it).

Prints one JSON object. Usage: python benchmarks/round_trip.py [--method tvf-large] [--decisions 20]
[--seed-start 1000001] [--bands 0,0.0001,0.001,0.003]. Decision i is unseen task i mod 8 with seed
``seed_start + 2 (i // 8)``. About 10 s a decision for TVF-L on one core.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

import numpy as np
import torch

from tvf.api import load_planner
from tvf.planning.search import Plan, best_node, root_values
from tvf.sim.env import TvfEnv
from tvf.tasks import BLOCK_SYMMETRY, load_tasks
from tvf.train.jobs import PICK_TOLERANCE_PX, PLACE_TOLERANCE_PX
from tvf.views import DEFAULT_DEPTH_SCALE, folder_workspace, load_rgbh, write_views


def action_key(node) -> tuple:
    return tuple(np.asarray(node.pick).tolist()), tuple(np.asarray(node.place).tolist()), int(node.rotation)


def first_action(plan: Plan, band: float) -> tuple:
    """The executed action of ``plan`` under a tie band."""
    node = plan.nodes[best_node(plan.nodes, band)]
    while node.parent >= 0:
        node = plan.nodes[node.parent]
    return action_key(node)


def subtree_values(plan: Plan) -> dict[tuple, float]:
    """Each root action's best score in its subtree (``tvf.planning.search.root_values``)."""
    _, value = root_values(plan.nodes)
    return {action_key(n): float(value[i]) for i, n in enumerate(plan.nodes) if n.parent < 0}


def physically_same(a: tuple, b: tuple, n_rotations: int = 36) -> bool:
    """The same block picked and put at the same place, by the GCTN's accuracy tolerances
    (``tvf.train.jobs``): pick within 6 px, place within 3 px, the rotation within one bin modulo a
    block's symmetry (a quarter turn)."""
    (pick_a, place_a, rot_a), (pick_b, place_b, rot_b) = a, b
    period = round(n_rotations * BLOCK_SYMMETRY / (2 * math.pi))
    turn = (rot_a - rot_b) % period
    pick_ok = np.abs(np.subtract(pick_a, pick_b)).max() <= PICK_TOLERANCE_PX
    place_ok = np.abs(np.subtract(place_a, place_b)).max() <= PLACE_TOLERANCE_PX
    return bool(pick_ok and place_ok and min(turn, period - turn) <= 1)


def roots(plan: Plan) -> list[tuple]:
    return sorted(action_key(n) for n in plan.nodes if n.depth == 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--method", default="tvf-large")
    parser.add_argument("--decisions", type=int, default=20)
    parser.add_argument("--seed-start", type=int, default=1_000_001)
    parser.add_argument("--bands", default="0,0.0001,0.001,0.003")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--depth-scale", type=float, default=DEFAULT_DEPTH_SCALE, help="metres per unit of the depth PNGs"
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    bands = [float(b) for b in args.bands.split(",")]
    tasks = load_tasks().resolve("unseen")
    planner = load_planner(args.method)
    searches = args.method != "gctn"
    agree = {b: 0 for b in bands}
    changed = {b: 0 for b in bands}
    same_roots, plain, maes, same_block, gaps = 0, 0, [], 0, []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.decisions):
            task, seed = tasks[i % len(tasks)], args.seed_start + 2 * (i // len(tasks))
            env = TvfEnv(task)
            try:
                obs, info = env.reset(seed=seed)
                rig = Path(tmp) / f"{task.name}-{seed}"
                write_views(rig / "scene", *env.world.views(), depth_scale=args.depth_scale)
                write_views(rig / "goal", *env.goal_views, depth_scale=args.depth_scale)
            finally:
                env.close()
            goal, ws = info["goal"], folder_workspace(rig / "scene")
            scene, goal_image = load_rgbh(rig / "scene", ws, "--views"), load_rgbh(rig / "goal", ws, "--goal")
            maes.append(float(np.abs(scene.height - obs["height"]).mean()))
            inside = planner.next_action(obs["color"], obs["height"], goal["color"], goal["height"])
            outside = planner.next_action(scene.color, scene.height, goal_image.color, goal_image.height)
            if not searches:
                plain += (inside.pick_pixel, inside.place_pixel, inside.rotation_bin) == (
                    outside.pick_pixel, outside.place_pixel, outside.rotation_bin)  # fmt: skip
                continue
            same_roots += roots(inside.plan) == roots(outside.plan)
            mine, theirs = first_action(inside.plan, 0.0), first_action(outside.plan, 0.0)
            same_block += physically_same(mine, theirs)
            if mine != theirs:
                values = subtree_values(inside.plan)
                gaps.append(None if theirs not in values else round(values[mine] - values[theirs], 6))
            for b in bands:
                agree[b] += first_action(inside.plan, b) == first_action(outside.plan, b)
                changed[b] += first_action(inside.plan, b) != first_action(inside.plan, 0.0)
    out = {
        "method": args.method,
        "decisions": args.decisions,
        "seed_start": args.seed_start,
        "depth_scale": args.depth_scale,
        "height_mae_mm": round(1000 * float(np.mean(maes)), 3),
        "agree": {str(b): n for b, n in agree.items()} if searches else plain,
    }
    if searches:
        out["same_root_proposals"] = same_roots
        out["physically_same"] = same_block
        out["score_gaps"] = gaps
        out["changed_by_band"] = {str(b): n for b, n in changed.items()}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
