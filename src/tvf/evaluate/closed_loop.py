"""Closed-loop evaluation: run a policy in the simulator on test seeds, write per-episode results
(``episodes.jsonl``, appended as episodes finish, so an interrupted evaluation resumes) and a summary
(``summary.json``, ``summary.md``) with Wilson 95% intervals."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tvf.errors import TvfError
from tvf.evaluate.runner import EpisodeResult, cached_env, run_episode, run_jobs
from tvf.viz.images import atomic_write_bytes

METHODS = ("oracle", "gctn", "tvf-small", "tvf-large")
_POLICIES: dict = {}


@dataclass(frozen=True)
class PolicySpec:
    """What to evaluate: a method and its checkpoints (None: the shipped weights) and planner overrides."""

    method: str
    gctn: str | None = None
    vf: str | None = None
    k: int | None = None
    depth: int | None = None
    step_slack: int = 0

    def planner(self):
        """The planner configuration of a TVF method (preset plus the K and depth overrides)."""
        from tvf.planning.search import planner_config

        try:
            return planner_config(self.method, self.k, self.depth)
        except (KeyError, ValueError) as exc:
            raise TvfError(
                f"{exc.args[0]}; TVF methods are tvf-small and tvf-large, with K, depth >= 1"
            ) from None


def make_policy(spec: PolicySpec):
    """The policy object of a spec (models are loaded here; errors name the bad flag)."""
    from tvf.evaluate.policies import GctnPolicy, OraclePolicy, TvfPolicy
    from tvf.train.trainer import pick_device

    device = str(pick_device("auto"))  # the models run on CUDA when there is one
    if spec.method == "oracle":
        return OraclePolicy()
    if spec.method == "gctn":
        return GctnPolicy(spec.gctn, device)
    if spec.method in METHODS:
        return TvfPolicy(spec.gctn, spec.vf, spec.planner(), device)
    raise TvfError(f"unknown method {spec.method!r}; choose one of {', '.join(METHODS)}")


def cached_policy(spec: PolicySpec):
    """This process's policy for ``spec`` (models are loaded once per process)."""
    if spec not in _POLICIES:
        _POLICIES[spec] = make_policy(spec)
    return _POLICIES[spec]


def policy_episode(task: str, seed: int, spec: PolicySpec) -> EpisodeResult:
    """One closed-loop episode: reset to ``seed``, act until success or the horizon (plus slack)."""
    policy = cached_policy(spec)
    env = cached_env(task)
    act = lambda obs, goal: policy.act(env, obs, goal)  # noqa: E731
    return run_episode(env, seed, act, env.task.horizon + spec.step_slack)


def wilson(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion."""
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


def summarise(results: list[dict], method: str) -> dict:
    """Per-task and average success (with Wilson 95% intervals) and mean progress."""
    tasks: dict[str, list[dict]] = {}
    for r in results:
        tasks.setdefault(r["task"], []).append(r)
    rows = []
    for name, rs in tasks.items():
        k = sum(bool(r["success"]) for r in rs)
        lo, hi = wilson(k, len(rs))
        rows.append({"task": name, "episodes": len(rs), "successes": k, "success": k / len(rs),
                     "ci95": [lo, hi], "progress": float(np.mean([r["progress"] for r in rs]))})  # fmt: skip
    k = sum(r["successes"] for r in rows)
    n = sum(r["episodes"] for r in rows)
    average = {
        "success": float(np.mean([r["success"] for r in rows])) if rows else 0.0,
        "ci95": list(wilson(k, n)),
        "progress": float(np.mean([r["progress"] for r in rows])) if rows else 0.0,
        "episodes": n,
    }
    return {"method": method, "tasks": rows, "average": average}


def summary_markdown(summary: dict) -> str:
    lines = [f"# Evaluation: {summary['method']}", "", "| task | episodes | success | 95% CI | progress |",
             "|---|---|---|---|---|"]  # fmt: skip
    rows = [
        (r["task"], r["episodes"], f"{r['success']:.1%}", r["ci95"], r["progress"]) for r in summary["tasks"]
    ]
    a = summary["average"]
    rows.append(("**average**", a["episodes"], f"**{a['success']:.1%}**", a["ci95"], a["progress"]))
    for name, n, rate, (lo, hi), progress in rows:
        lines.append(f"| {name} | {n} | {rate} | {lo:.0%}–{hi:.0%} | {progress:.1%} |")
    return "\n".join(lines) + "\n"


def read_results(path: Path) -> list[dict]:
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:  # a line cut by an interruption: that episode is re-run
            continue
    return out


def evaluate(
    spec: PolicySpec, task_names: list[str], episodes: int, seed_start: int, workers: int, out: Path,
    task_file: str | None = None,
) -> dict:  # fmt: skip
    """Evaluate on seeds ``seed_start + 2i`` (odd = test seeds by default) and write the outputs."""
    out.mkdir(parents=True, exist_ok=True)
    log = out / "episodes.jsonl"
    meta = {**asdict(spec), "episodes": episodes, "seed_start": seed_start}
    meta_path = out / "eval.json"
    if meta_path.exists() and json.loads(meta_path.read_text()) != meta:
        raise TvfError(f"{out} holds an evaluation with other settings ({meta_path}); choose another --out")
    atomic_write_bytes(meta_path, json.dumps(meta, indent=1).encode())
    done = {(r["task"], r["seed"]): r for r in read_results(log)}
    jobs = [(t, seed_start + 2 * i) for t in task_names for i in range(episodes)]
    todo = [(t, s, spec) for t, s in jobs if (t, s) not in done]
    if len(todo) < len(jobs):
        print(f"resuming: {len(jobs) - len(todo)} of {len(jobs)} episodes already in {log}")
    with log.open("a") as f:
        for result in run_jobs(policy_episode, todo, workers, f"eval {spec.method}", task_file):
            record = result.to_dict()
            done[(record["task"], record["seed"])] = record
            f.write(json.dumps(record) + "\n")
            f.flush()
    results = [done[j] for j in jobs]
    summary = summarise(results, spec.method)
    atomic_write_bytes(out / "summary.json", json.dumps(summary, indent=1).encode())
    atomic_write_bytes(out / "summary.md", summary_markdown(summary).encode())
    return summary
