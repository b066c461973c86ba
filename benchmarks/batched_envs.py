"""Batched environments (`tvf eval --envs-per-worker N`): seconds per episode-step, 1 vs N per process.

``--episodes`` episodes of ``--task`` (validation seeds 1, 3, ...) are cut to ``--steps`` steps each and
run in groups of N environments stepped in lock-step (:func:`tvf.evaluate.runner.run_episodes`), for
every N of ``--envs``, with the shipped lite weights (``--method``, default TVF-L) on one process with
``--threads`` torch threads (the evaluation set-up: one thread per worker). Reported per N: wall seconds
per episode-step, of which deciding (the policy), this process's CPU seconds per episode-step (less
noisy on a shared machine) and whether the episodes equal those of N = 1.

On the CPU environments keep their own model calls (bit-identical decisions, tvf.device); ``--mix``
also times the GPU's way there (rows of all N environments in one call per level). CUDA, when present
and asked for with ``--device cuda``, always mixes.

Prints one JSON object. Usage: python benchmarks/batched_envs.py [--method tvf-large] [--task stack-pyramid]
[--episodes 4] [--steps 2] [--envs 1,2,4] [--mix] [--threads 1] [--device cpu]
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from tvf.evaluate.runner import batch_envs, run_episodes
from tvf.policies import PolicySpec, make_policy
from tvf.sim.factory import SimEnvFactory
from tvf.tasks import get_task


class Timed:
    """A batch policy that adds up the seconds its decisions take."""

    def __init__(self, policy, sync) -> None:
        self.policy, self.sync, self.name, self.seconds = policy, sync, policy.name, 0.0

    def reset(self) -> None:
        self.policy.reset()

    def act(self, obs, goal):
        return self.act_batch([obs], [goal])[0]

    def act_batch(self, observations, goals):
        start = time.perf_counter()
        actions = self.policy.act_batch(observations, goals)
        self.sync()
        self.seconds += time.perf_counter() - start
        return actions


def run(policy: Timed, task, seeds: list[int], n: int, steps: int) -> tuple[float, float, list[dict]]:
    """Wall and CPU seconds (this process) and results of the episodes in groups of ``n`` environments."""
    results = []
    start, cpu = time.perf_counter(), time.process_time()
    for i in range(0, len(seeds), n):
        group = seeds[i : i + n]
        envs = batch_envs(SimEnvFactory(), [task] * len(group))
        results += [r.to_dict() for r in run_episodes(envs, group, [policy] * len(group), steps)]
    return time.perf_counter() - start, time.process_time() - cpu, results


def set_mix(policy, mix: bool | None) -> None:
    if hasattr(policy, "search"):
        policy.search.mix_roots = mix
    else:
        policy.mix = mix


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--method", default="tvf-large")
    parser.add_argument("--task", default="stack-pyramid")
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--steps", type=int, default=2)
    parser.add_argument("--envs", default="1,2,4")
    parser.add_argument("--mix", action="store_true", help="also time environments sharing model calls")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    task = get_task(args.task)
    seeds = [1 + 2 * i for i in range(args.episodes)]
    policy = Timed(make_policy(PolicySpec(args.method, device=args.device)), sync)
    run(policy, task, seeds[:1], 1, 1)  # warm-up: models, worlds
    modes = [(n, None) for n in map(int, args.envs.split(","))]
    modes += [(n, True) for n, _ in modes if n > 1 and args.mix and device.type == "cpu"]
    out, reference = {}, None
    for n, mix in modes:
        set_mix(policy.policy, mix)
        policy.seconds = 0.0
        seconds, cpu, results = run(policy, task, seeds, n, args.steps)
        steps = sum(r["steps"] for r in results) or 1
        reference = results if reference is None else reference
        out[f"{n}{' mixed' if mix else ''}"] = {
            "s_per_episode_step": seconds / steps, "cpu_s_per_episode_step": cpu / steps,
            "decide_s_per_episode_step": policy.seconds / steps,
            "episode_steps": steps, "same_episodes_as_first": results == reference,
        }  # fmt: skip
    meta = {"method": args.method, "task": args.task, "episodes": args.episodes, "steps": args.steps,
            "threads": args.threads, "device": str(device)}  # fmt: skip
    print(json.dumps({"batched_envs": out, **meta}, indent=1))


if __name__ == "__main__":
    main()
