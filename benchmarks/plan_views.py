"""What planning from a real rig's files costs on top of the decision: read and fuse the views of the
scene (three 480 x 360 cameras as `tvf render --export-views` writes them) against one TVF-L decision
with the shipped `lite` weights, side by side in one run (issue 13's target: fusing adds at most 20 %).

Prints one JSON object. Usage: python benchmarks/plan_views.py [--task put-t] [--seed 1] [--repeats 3]
[--threads 1] [--sensor ideal|one]. The goal is read as a saved RGB-H image (a real set-up records it
once per task, not per decision).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import torch

from common import best_seconds
from tvf.api import load_planner
from tvf.sim.env import TvfEnv
from tvf.tasks import BUILTIN
from tvf.views import fuse_views, read_views, write_views


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--task", default="put-t")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--sensor", default="ideal", help="the rig whose views are fused (tvf.sim.sensors)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    env = TvfEnv(BUILTIN.get(args.task), sensor=args.sensor)
    _, info = env.reset(seed=args.seed)
    goal = info["goal"]
    planner = load_planner("tvf-large")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "scene"
        views, cameras = env.sensed_views()
        write_views(folder, views, cameras, env.world.workspace)
        ws = env.world.workspace

        def read_and_fuse():
            return fuse_views(read_views(folder), ws, folder)

        scene = read_and_fuse()
        fuse_s = best_seconds(read_and_fuse, args.repeats)
        read_s = best_seconds(lambda: read_views(folder), args.repeats)
    decide_s = best_seconds(
        lambda: planner.next_action(scene.color, scene.height, goal["color"], goal["height"]), args.repeats
    )
    print(json.dumps({
        "task": args.task, "seed": args.seed, "sensor": args.sensor, "threads": args.threads,
        "cameras": len(cameras), "read_views_s": read_s, "read_and_fuse_s": fuse_s,
        "tvf_large_decision_s": decide_s, "fusion_share_of_decision": fuse_s / decide_s,
    }, indent=1))  # fmt: skip


if __name__ == "__main__":
    main()
