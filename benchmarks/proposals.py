"""How distinct are the planner's root proposals? The paper's K-means rule against NMS and pick branching.

For the unseen tasks, each scene is the first observation of a validation seed (odd seeds 1, 3, 5, ...)
and, for the first ``--mid`` seeds, also the state after one oracle step. The shipped lite GCTN and VF
plan one level (K proposals, their imagined outcomes) under each rule. Per rule the script reports:

* ``all_distinct``: the fraction of decisions whose proposals are K pairwise distinct actions; two
  actions are distinct when ``max(pick distance, place distance) >= 13 px`` (one block): they place
  a block at least a block apart, or move a different block (branched picks are >= 13 px apart);
* ``returned_distinct``: the same, counting decisions with fewer than K proposals too;
* ``mean_proposals``, ``mean_picks``: proposals and distinct picks per decision;
* ``median_closest_px``: the median over decisions of the closest pair's action distance;
* ``all_within_block``: the fraction whose proposals all lie within one block of each other;
* ``median_score_spread``: the median best-minus-worst child score (how different the imagined
  outcomes are; the discount and the constant C cancel);
* ``place_on_ready_target``, ``greedy_on_ready_target``: the fraction of decisions where some
  proposal (resp. the first one, the GCTN's own action) places within 8 px (half the 5 cm cell
  spacing) of a target the expert could fill next (the pick is not checked);
* ``decision_s``: median seconds of that one-level decision (GCTN, proposals, VF on K children) and
  ``tvf_large_s``: one depth-3 decision on the first ``--large`` scenes (median).

With ``--methods tvf-large[,...]`` each named method is measured too, as the registry builds it (its
GCTN symmetrised and goal-masked as shipped, its planner settings; ``--order-branch`` adds each method
with one ordered place per node, which needs its goal mask; ``--alphas 0.001,...`` adds each method
with each of those alphas, ``--root-alphas`` with each as ``--root-alpha``): rows ``method:NAME``.

Prints one JSON object. Usage: python benchmarks/proposals.py [--seeds 10] [--mid 5] [--k 3]
[--threads 1] [--large 2] [--methods tvf-large] [--order-branch] [--only-methods] [--alphas A,...]
[--root-alphas A,...]
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
import time
from dataclasses import replace

import numpy as np
import torch

from tvf.geometry import world_to_pixel
from tvf.models.checkpoint import load_trained
from tvf.models.images import to_rgbh
from tvf.planning.search import PlannerConfig, TreeSearch
from tvf.policies import PolicySpec, make_policy
from tvf.seeds import seed_range
from tvf.sim.factory import sim_env
from tvf.sim.oracle import ready_targets
from tvf.tasks import resolve_tasks

BLOCK_PX = 13.0
TARGET_PX = 8.0


def variants(k: int) -> dict[str, dict]:
    """The rules compared (PlannerConfig fields)."""
    out = {
        "kmeans": {},
        "nms": {"proposals": "nms"},
        "nms-alpha0.001": {"proposals": "nms", "alpha": 0.001},
        "nms-rot30": {"proposals": "nms", "nms_rotation": 30.0},
    }
    for p in range(2, min(k, 3) + 1):
        out[f"nms+picks{p}"] = {"proposals": "nms", "pick_branches": p}
    out[f"nms+picks{min(k, 3)}-alpha0.001"] = {"proposals": "nms", "pick_branches": min(k, 3), "alpha": 0.001}
    return out


def scenes(n_seeds: int, n_mid: int) -> list[dict]:
    """First observations of the validation seeds, and states after one oracle step."""
    out = []
    for task in resolve_tasks("unseen"):
        env = sim_env(task)
        for i in range(n_seeds):
            seed = 2 * i + 1
            assert seed_range(seed) == "validation"
            steps = [0, 1] if i < n_mid else [0]
            obs, info = env.reset(seed=seed)
            goal = to_rgbh(info["goal"]["color"], info["goal"]["height"])
            for step in steps:
                if step:
                    action = env.oracle_action()
                    if action is None:
                        break
                    obs, _, terminated, truncated, _ = env.step(action)
                    if terminated or truncated:
                        break
                tpos, _ = env.world.target_poses()
                ready = ready_targets(env.world, env.order)
                targets = world_to_pixel(tpos[ready, :2]) if ready else np.zeros((0, 2))
                current = to_rgbh(obs["color"], obs["height"])
                out.append(
                    dict(task=task.name, seed=seed, step=step, current=current, goal=goal, targets=targets)
                )
    return out


def action_distances(picks: np.ndarray, places: np.ndarray) -> np.ndarray:
    """max(pick distance, place distance) of every pair of proposals."""
    pairs = list(itertools.combinations(range(len(places)), 2))
    return np.array(
        [max(np.hypot(*(picks[i] - picks[j])), np.hypot(*(places[i] - places[j]))) for i, j in pairs]
    )


def decide(search: TreeSearch, scene: dict) -> tuple[object, float]:
    start = time.perf_counter()
    plan = search.search(scene["current"], scene["goal"])
    return plan, time.perf_counter() - start


def evaluate(gctn, vf, config: PlannerConfig, items: list[dict], n_large: int) -> dict:
    """The distinctness of ``config``'s root proposals (one level) over ``items``, and the time of a
    depth-3 decision with it on the first ``n_large``."""
    k = config.k
    search = TreeSearch(gctn, vf, replace(config, depth=1))
    decide(search, items[0])  # warm-up
    rows = []
    for scene in items:
        plan, seconds = decide(search, scene)
        prop = plan.root_proposals
        d = action_distances(prop.picks, prop.places)
        scores = [n.score for n in plan.nodes]
        near = (
            np.hypot(*(prop.places[:, None] - scene["targets"][None]).transpose(2, 0, 1)) <= TARGET_PX
            if len(scene["targets"])
            else np.zeros((len(prop), 1), dtype=bool)
        )
        rows.append(
            dict(
                n=len(prop),
                picks=len({tuple(p) for p in prop.picks.tolist()}),
                distinct=bool((d >= BLOCK_PX).all()),
                closest=float(d.min()) if len(d) else None,
                within=bool(len(d) and (d < BLOCK_PX).all()),
                spread=max(scores) - min(scores),
                hit=bool(near.any()),
                greedy_hit=bool(near[0].any()),
                seconds=seconds,
            )
        )
    large = TreeSearch(gctn, vf, replace(config, depth=3))
    large_s = [decide(large, scene)[1] for scene in items[:n_large]]

    def mean(key: str) -> float:
        return round(float(np.mean([r[key] for r in rows])), 4)

    closest = [r["closest"] for r in rows if r["closest"] is not None]
    return {
        "decisions": len(rows),
        "all_distinct": round(float(np.mean([r["distinct"] and r["n"] == k for r in rows])), 4),
        "returned_distinct": mean("distinct"),
        "mean_proposals": mean("n"),
        "mean_picks": mean("picks"),
        "median_closest_px": round(statistics.median(closest), 2) if closest else None,
        "all_within_block": mean("within"),
        "median_score_spread": round(statistics.median(r["spread"] for r in rows), 5),
        "place_on_ready_target": mean("hit"),
        "greedy_on_ready_target": mean("greedy_hit"),
        "decision_s": round(statistics.median(r["seconds"] for r in rows), 4),
        "tvf_large_s": round(statistics.median(large_s), 3) if large_s else None,
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, default=10, help="validation seeds per task (1, 3, 5, ...)")
    parser.add_argument("--mid", type=int, default=5, help="of those, how many also give a mid-episode state")
    parser.add_argument("--k", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--large", type=int, default=2, help="scenes timed with a depth-3 search")
    parser.add_argument("--methods", default="", help="comma-separated methods measured as shipped")
    parser.add_argument("--order-branch", action="store_true", help="also each method with --order-branch")
    parser.add_argument("--only-methods", action="store_true", help="skip the plain GCTN's rule rows")
    parser.add_argument("--alphas", default="", help="comma-separated alphas: each method also with each")
    parser.add_argument(
        "--root-alphas", default="", help="comma-separated root alphas: each method also with each"
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    gctn, vf = load_trained(None, "gctn"), load_trained(None, "vf")
    items = scenes(args.seeds, args.mid)
    rules = {} if args.only_methods else variants(args.k)
    results = {
        name: evaluate(gctn, vf, PlannerConfig(k=args.k, depth=1, **changes), items, args.large)
        for name, changes in rules.items()
    }
    alphas = [{}, *({"alpha": float(a)} for a in filter(None, args.alphas.split(",")))]
    alphas += [{"root_alpha": float(a)} for a in filter(None, args.root_alphas.split(","))]
    for method in filter(None, args.methods.split(",")):
        for order, alpha in itertools.product((False, True) if args.order_branch else (False,), alphas):
            spec = PolicySpec(method, order_branch=order or None, device="cpu", **alpha)
            policy = make_policy(spec)
            name = (
                f"method:{method}"
                + ("+order-branch" if order else "")
                + "".join(f"+{field.replace('_', '-')}={value:g}" for field, value in alpha.items())
            )
            results[name] = evaluate(policy.search.gctn, vf, policy.search.config, items, args.large)
    meta = {
        "k": args.k,
        "scenes": len(items),
        "first_observations": sum(s["step"] == 0 for s in items),
        "after_one_oracle_step": sum(s["step"] == 1 for s in items),
        "seeds": f"odd 1..{2 * args.seeds - 1} (validation range)",
        "tasks": sorted({s["task"] for s in items}),
        "threads": args.threads,
        "block_px": BLOCK_PX,
    }
    print(json.dumps({"proposals": results, **meta}, indent=1))


if __name__ == "__main__":
    main()
