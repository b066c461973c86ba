"""Does the goal-difference mask (``--goal-mask``, tvf.models.goal_mask) keep the expert's actions?

The expert (the scripted oracle) plays validation seeds (odd, 1, 3, ...) of the chosen tasks; at every
state the script checks that its pick pixel lies where the mask allows picks and its place pixel where
it allows places, and how much of the image each mask leaves. It reads only the simulator and the mask
(no learned model). Prints one JSON object: ``steps``, ``pick_kept`` / ``place_kept`` (the fractions of
expert actions inside the masks), ``pick_share`` / ``place_share`` (the mean fraction of pixels each
mask allows) and the steps that fell outside, if any. ``--places RULE`` checks the places against one of
the mask's place rules (``--mask-places``: gap, centred, bottom-up, ordered), ``--share S`` with the
centring's share (``--centred-share``).

Usage: python benchmarks/goal_mask.py [--tasks unseen] [--seeds 2] [--max-steps 12] [--places gap]
[--share 0.9]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

import tvf.envs  # noqa: F401  (registers the environments)
from tvf.geometry import world_to_pixel
from tvf.models.goal_mask import CENTRED_SHARE, PLACE_RULES, pick_allowed, place_allowed
from tvf.policies.learned import observation_tensor
from tvf.sim.factory import sim_env
from tvf.tasks import BUILTIN


def expert_states(task, seed: int, max_steps: int):
    """(observation, goal, expert action) along the expert's episode of ``task`` at ``seed``."""
    env = sim_env(task)  # this process's simulator for the task, kept open for the next seed
    obs, _ = env.reset(seed=seed)
    for _ in range(max_steps):
        action = env.oracle_action()
        if action is None:
            return
        yield obs, obs["desired_goal"], np.asarray(action)
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            return


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--tasks", default="unseen", help="unseen | train | all | comma-separated names")
    parser.add_argument("--seeds", type=int, default=2, help="validation seeds per task (1, 3, ...)")
    parser.add_argument("--max-steps", type=int, default=12)
    parser.add_argument("--places", default="gap", choices=PLACE_RULES, help="the mask's place rule")
    parser.add_argument(
        "--share", type=float, default=CENTRED_SHARE, help="centred and ordered: the centring's share"
    )
    args = parser.parse_args()
    cpu = torch.device("cpu")
    kept, shares, misses = [], [], []
    for task in BUILTIN.resolve(args.tasks):
        for seed in range(1, 2 * args.seeds, 2):
            for step, (obs, goal, action) in enumerate(expert_states(task, seed, args.max_steps)):
                current, target = observation_tensor(obs, cpu), observation_tensor(goal, cpu)
                picks, places = (
                    pick_allowed(current, target)[0].numpy(),
                    place_allowed(current, target, rule=args.places, share=args.share)[0].numpy(),
                )
                pick, place = world_to_pixel(action[0, :2]), world_to_pixel(action[1, :2])
                inside = (bool(picks[tuple(pick)]), bool(places[tuple(place)]))
                kept.append(inside)
                shares.append((picks.mean(), places.mean()))
                if not all(inside):
                    misses.append({"task": task.name, "seed": seed, "step": step, "pick_kept": inside[0]})
    kept_mean, share_mean = np.mean(kept, axis=0), np.mean(shares, axis=0)
    print(json.dumps({
        "tasks": args.tasks, "seeds": args.seeds, "places": args.places, "share": args.share,
        "steps": len(kept),
        "pick_kept": float(kept_mean[0]), "place_kept": float(kept_mean[1]),
        "pick_share": float(share_mean[0]), "place_share": float(share_mean[1]), "misses": misses,
    }, indent=1))  # fmt: skip


if __name__ == "__main__":
    main()
