"""Does the goal-difference mask (``--goal-mask``, tvf.models.goal_mask) keep the expert's actions?

The expert (the scripted oracle) plays validation seeds (odd, 1, 3, ...) of the chosen tasks; at every
state the script checks that its pick pixel lies where the mask allows picks and its place pixel where
it allows places, and how much of the image each mask leaves. It reads only the simulator and the mask
(no learned model). Prints one JSON object: ``steps``, ``pick_kept`` / ``place_kept`` (the fractions of
expert actions inside the masks), ``pick_share`` / ``place_share`` (the mean fraction of pixels each
mask allows) and the steps that fell outside, if any. ``--places RULE`` checks the places against one of
the mask's place rules (``--mask-places``: gap, centred, bottom-up, ordered, layered, cells), ``--share S``
with the centring's share (``--centred-share``). For the rules that narrow the places to a few pixels per
cell, ``off_grid_share`` says how many of the connected blobs of kept places lie with their middle more than
``OFF_GRID_PX`` from every target cell's middle (a block put there lands off its cell), ``blob_px_median``
the median of those distances.

Usage: python benchmarks/goal_mask.py [--tasks unseen] [--seeds 2] [--seed-start 1] [--max-steps 12]
[--places gap] [--share 0.9]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch
from scipy import ndimage

import tvf.envs  # noqa: F401  (registers the environments)
from tvf.geometry import world_to_pixel
from tvf.models.goal_mask import CENTRED_SHARE, PLACE_RULES, pick_allowed, place_allowed
from tvf.policies.learned import observation_tensor
from tvf.sim.factory import sim_env
from tvf.tasks import BUILTIN

OFF_GRID_PX = 2.5
"""A blob of kept places whose middle lies further than this (pixels, 8 mm) from every target cell's middle
is off the cell grid."""


def expert_states(task, seed: int, max_steps: int):
    """(observation, goal, expert action, target cells' pixels) along the expert's episode of ``task`` at
    ``seed``."""
    env = sim_env(task)  # this process's simulator for the task, kept open for the next seed
    obs, _ = env.reset(seed=seed)
    cells = world_to_pixel(env.world.target_poses()[0][:, :2]).astype(float)
    for _ in range(max_steps):
        action = env.oracle_action()
        if action is None:
            return
        yield obs, obs["desired_goal"], np.asarray(action), cells
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            return


def blob_distances(places: np.ndarray, cells: np.ndarray) -> list[float]:
    """Each connected blob of ``places`` (H, W): its middle's distance in pixels to the nearest of ``cells``
    (N, 2)."""
    labels, count = ndimage.label(places)
    middles = ndimage.center_of_mass(places, labels, range(1, count + 1))
    return [float(np.linalg.norm(cells - np.asarray(m), axis=1).min()) for m in middles]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--tasks", default="unseen", help="unseen | train | all | comma-separated names")
    parser.add_argument("--seeds", type=int, default=2, help="validation seeds per task (odd)")
    parser.add_argument("--seed-start", type=int, default=1, help="the first validation seed (odd)")
    parser.add_argument("--max-steps", type=int, default=12)
    parser.add_argument("--places", default="gap", choices=PLACE_RULES, help="the mask's place rule")
    parser.add_argument(
        "--share", type=float, default=CENTRED_SHARE, help="centred and ordered: the centring's share"
    )
    args = parser.parse_args()
    cpu = torch.device("cpu")
    kept, shares, misses, blob_px = [], [], [], []
    for task in BUILTIN.resolve(args.tasks):
        for seed in range(args.seed_start, args.seed_start + 2 * args.seeds, 2):
            for step, (obs, goal, action, cells) in enumerate(expert_states(task, seed, args.max_steps)):
                current, target = observation_tensor(obs, cpu), observation_tensor(goal, cpu)
                picks, places = (
                    pick_allowed(current, target)[0].numpy(),
                    place_allowed(current, target, rule=args.places, share=args.share)[0].numpy(),
                )
                pick, place = world_to_pixel(action[0, :2]), world_to_pixel(action[1, :2])
                inside = (bool(picks[tuple(pick)]), bool(places[tuple(place)]))
                kept.append(inside)
                blob_px.extend(blob_distances(places, cells))
                shares.append((picks.mean(), places.mean()))
                if not all(inside):
                    misses.append({"task": task.name, "seed": seed, "step": step, "pick_kept": inside[0]})
    kept_mean, share_mean = np.mean(kept, axis=0), np.mean(shares, axis=0)
    print(json.dumps({
        "tasks": args.tasks, "seeds": args.seeds, "places": args.places, "share": args.share,
        "steps": len(kept),
        "pick_kept": float(kept_mean[0]), "place_kept": float(kept_mean[1]),
        "pick_share": float(share_mean[0]), "place_share": float(share_mean[1]),
        "place_blobs": len(blob_px),
        "off_grid_share": float(np.mean(np.asarray(blob_px) > OFF_GRID_PX)) if blob_px else None,
        "blob_px_median": float(np.median(blob_px)) if blob_px else None, "misses": misses,
    }, indent=1))  # fmt: skip


if __name__ == "__main__":
    main()
