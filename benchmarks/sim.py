"""Simulator costs on one core: seconds per observation, per pick-and-place, oracle episodes per minute.

Prints one JSON object. Usage: python benchmarks/sim.py [--episodes N] [--task NAME]
"""

from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from tvf.sim.env import TvfEnv  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=3, help="oracle episodes per task")
    parser.add_argument("--tasks", default="stack-pyramid,put-plane,stack-twin-tower")
    args = parser.parse_args()
    obs_times, pp_times, pp_steps, ep_times = [], [], [], []
    for name in args.tasks.split(","):
        env = TvfEnv(name)
        for seed in range(args.episodes):
            t_ep = time.perf_counter()
            env.reset(seed=seed)
            for _ in range(env.task.horizon):
                action = env.oracle_action()
                if action is None:
                    break
                t0 = time.perf_counter()
                result = env.world.arm.pick_and_place(action[0], action[1], set(env.world.blocks))
                env.world.settle()
                pp_times.append(time.perf_counter() - t0)
                pp_steps.append(result.steps)
                t0 = time.perf_counter()
                env.world.observe()
                obs_times.append(time.perf_counter() - t0)
            ep_times.append(time.perf_counter() - t_ep)
        env.close()
    print(
        json.dumps(
            {
                "seconds_per_observation": float(np.median(obs_times)),
                "seconds_per_pick_and_place": float(np.median(pp_times)),
                "seconds_per_pick_and_place_mean": float(np.mean(pp_times)),
                "physics_steps_per_pick_and_place": float(np.mean(pp_steps)),
                "oracle_episodes_per_minute": 60.0 / float(np.mean(ep_times)),
                "episodes": len(ep_times),
                "tasks": args.tasks.split(","),
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
