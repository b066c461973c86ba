"""Closed-loop evaluation: run a policy in the simulator on test seeds, write per-episode results
(``episodes.jsonl``, appended as episodes finish, so an interrupted evaluation resumes) and a summary
(``summary.json``, ``summary.md``) with Wilson 95% intervals. A full disk stops it with one
:class:`~tvf.errors.DiskFullError` saying how many episodes are kept (the log holds whole lines only)."""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np

from tvf.envs import EnvFactory
from tvf.errors import StaleError
from tvf.evaluate.runner import EpisodeResult, check_envs_per_worker, policy_episode, policy_episodes
from tvf.io import append_jsonl, as_disk_full, atomic_write_bytes, atomic_write_json, read_json, read_jsonl
from tvf.models.checkpoint import trained_checkpoint
from tvf.models.goal_mask import CENTRED_SHARE, CENTRING_RULES
from tvf.parallel import check_backend, run_jobs
from tvf.policies import (
    PolicySpec,
    centre_picks_of,
    centred_share_of,
    foresight_of,
    get_method,
    goal_mask_of,
    mask_places_of,
    planner_of,
    refine_yaw_of,
    resolved_settings,
)
from tvf.seeds import episode_seeds
from tvf.sim.factory import SimEnvFactory
from tvf.sim.sensors import get_sensor
from tvf.sim.success import MISS_KINDS
from tvf.tasks import BUILTIN, Task
from tvf.weights import sha256_file


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
    summary = {"method": method, "tasks": rows, "average": average}
    misses = miss_counts(results)
    if misses is not None:
        summary["misses"] = misses
    return summary


def miss_counts(results: list[dict]) -> dict | None:
    """The unfilled targets of the failed episodes by kind (:data:`tvf.sim.success.MISS_KINDS`), per task
    and over all; None where no record holds ``misses`` (older records, other worlds)."""
    failed = [r for r in results if not r["success"] and "misses" in r]
    if not any("misses" in r for r in results):
        return None
    per_task: dict[str, dict[str, int]] = {}
    for r in failed:
        counts = per_task.setdefault(r["task"], dict.fromkeys(MISS_KINDS, 0))
        for miss in r["misses"]:
            counts[miss["kind"]] += 1
    total = {kind: sum(c[kind] for c in per_task.values()) for kind in MISS_KINDS}
    one = sum(len(r["misses"]) == 1 for r in failed)
    return {"failed": len(failed), "one_target": one, "targets": total, "tasks": per_task}


def summary_markdown(summary: dict) -> str:
    seen = f" ({summary['foresight']} foresight)" if "foresight" in summary else ""
    lines = [f"# Evaluation: {summary['method']}{seen}", "",
             "| task | episodes | success | 95% CI | progress |", "|---|---|---|---|---|"]  # fmt: skip
    rows = [
        (r["task"], r["episodes"], f"{r['success']:.1%}", r["ci95"], r["progress"]) for r in summary["tasks"]
    ]
    a = summary["average"]
    rows.append(("**average**", a["episodes"], f"**{a['success']:.1%}**", a["ci95"], a["progress"]))
    for name, n, rate, (lo, hi), progress in rows:
        lines.append(f"| {name} | {n} | {rate} | {lo:.0%}–{hi:.0%} | {progress:.1%} |")
    misses = summary.get("misses")
    if misses and misses["failed"]:
        kinds = ", ".join(f"{kind} {n}" for kind, n in misses["targets"].items())
        lines += ["", f"Failed episodes: {misses['failed']}, {misses['one_target']} of them by one target. "
                  f"Their unfilled targets by the nearest block: {kinds} (turn: in place, turned; offset: "
                  "on its level, 1 cm to half a cell off; level: on its cell at another height; away: "
                  "none within half a cell)."]  # fmt: skip
    return "\n".join(lines) + "\n"


def read_results(path: Path) -> list[dict]:
    """The episode records of an ``episodes.jsonl`` (a line cut by an interruption is re-run)."""
    return read_jsonl(path)


def evaluate(
    spec: PolicySpec, tasks: Sequence[Task | str], episodes: int, seed_start: int, workers: int, out: Path,
    step_slack: int = 0, envs: EnvFactory | None = None, restart: bool = False, envs_per_worker: int = 1,
    backend: str = "local", address: str | None = None,
) -> dict:  # fmt: skip
    """Evaluate ``spec`` on seeds :func:`~tvf.evaluate.runner.episode_seeds` of every task; write the outputs.

    ``tasks`` are :class:`Task` values (names are looked up in the built-in table); ``envs`` makes the
    world of each task (default: the simulator) and must pickle when ``workers`` > 1. With
    ``envs_per_worker`` N > 1 each job is a group of N consecutive episodes that one process steps in
    lock-step, their decisions batched (:func:`~tvf.evaluate.runner.policy_episodes`); the records are
    those of one episode at a time, committed in the same order. ``backend`` and ``address`` choose where
    the jobs run (:func:`tvf.parallel.run_jobs`: the records are written here, in seed order, whatever ran
    them, and the backend is not a setting of the evaluation). A resume is keyed
    on the settings and on the content (SHA-256) of the weights files: when either changed, the folder is
    refused, naming what changed, or with ``restart`` its episodes are dropped and run again. A full
    disk is a :class:`~tvf.errors.DiskFullError` counting the episodes kept.
    """
    check_backend(backend, address)
    envs = envs or SimEnvFactory()
    check_envs_per_worker(envs_per_worker, envs)
    tasks = [t if isinstance(t, Task) else BUILTIN.get(t) for t in tasks]
    out.mkdir(parents=True, exist_ok=True)
    log = out / "episodes.jsonl"
    meta = {**asdict(spec), "episodes": episodes, "seed_start": seed_start, "step_slack": step_slack}
    meta.pop("device")
    # resolved, so that a folder of an unmasked GCTN is not resumed with a default that now masks it
    # (None, the value of folders from before the flag, is recorded for every unmasked method)
    meta["goal_mask"] = goal_mask_of(spec) or None
    places = mask_places_of(spec)  # likewise None for the mask's first rule, gap, and for no mask
    meta["mask_places"] = places if goal_mask_of(spec) and places != "gap" else None
    share = centred_share_of(spec)  # likewise None for the first centring, and where nothing is centred
    centring = meta["mask_places"] in CENTRING_RULES and share != CENTRED_SHARE
    meta["centred_share"] = share if centring else None
    meta["refine_yaw"] = refine_yaw_of(spec) or None  # resolved like the mask; None: the bins' own turns
    meta["centre_picks"] = centre_picks_of(spec) or None  # likewise; None: the GCTN's own pick pixels
    # resolved too (None: alpha at the root as everywhere), so a folder from before TVF-L's lower root
    # threshold is not resumed under it
    meta["root_alpha"] = planner_of(spec).root_alpha if get_method(spec.method).planner else None
    # likewise TVF-S's tie band (None: 0, the paper's rule, as folders from before it recorded)
    meta["tie_band"] = (planner_of(spec).tie_band or None) if get_method(spec.method).planner else None
    # and everything the method acts with, defaults filled in, so that a default changed since cannot
    # resume a folder under other rules (folders from before this record are trusted on the keys above)
    meta["resolved"] = resolved_settings(spec)
    meta["weights"] = weights_hashes(spec)
    if not isinstance(envs, SimEnvFactory):  # another world: recorded, so a resume cannot mix the two
        meta["env"] = f"{type(envs).__module__}.{type(envs).__qualname__}"
    elif not envs.ideal:  # the simulator through another sensor (tvf.sim.sensors): recorded likewise
        meta["sensor"] = envs.describe()
        fill = get_sensor(envs.sensor).hole_fill
        if fill != "nearest":  # presets changed their filling once: a resume must not mix the two
            meta["hole_fill"] = fill
    meta_path = out / "eval.json"
    if meta_path.exists() and not restart:
        changed = _changed_settings(meta_path, meta)
        if changed:
            raise StaleError(
                f"{out} holds an evaluation with other {', '.join(changed)} ({meta_path}); "
                "use the same flags, pass --restart to run it again, or choose another --out"
            )
    if restart:
        for stale in (log, out / "summary.json", out / "summary.md"):
            stale.unlink(missing_ok=True)
    jobs = [(t, s) for t in tasks for s in episode_seeds(seed_start, episodes)]
    try:
        where = {"backend": backend, "address": address}
        return _run_and_summarise(spec, jobs, step_slack, envs, workers, out, meta, envs_per_worker, where)
    except Exception as exc:
        full = as_disk_full(exc, out)
        if full is None:
            raise
        kept = {(r.get("task"), r.get("seed")) for r in read_results(log)}
        raise full.keeping(f"{len(kept)} of {len(jobs)} episodes kept in {log}") from exc


def _run_and_summarise(
    spec: PolicySpec, jobs: list[tuple[Task, int]], step_slack: int, envs: EnvFactory, workers: int,
    out: Path, meta: dict, envs_per_worker: int = 1, where: dict | None = None,
) -> dict:  # fmt: skip
    """Record the settings, run the episodes not yet in ``episodes.jsonl`` and write the summary (``where``:
    the ``backend`` and ``address`` of :func:`~tvf.parallel.run_jobs`)."""
    log = out / "episodes.jsonl"
    atomic_write_json(out / "eval.json", meta)
    done = {(r["task"], r["seed"]): r for r in read_results(log)}
    todo = [(t, s) for t, s in jobs if (t.name, s) not in done]
    if len(todo) < len(jobs):
        print(f"resuming: {len(jobs) - len(todo)} of {len(jobs)} episodes already in {log}")
    for result in _episode_results(spec, todo, step_slack, envs, workers, envs_per_worker, where or {}):
        record = result.to_dict()
        done[(record["task"], record["seed"])] = record
        append_jsonl(log, record)
    results = [done[(t.name, s)] for t, s in jobs]
    summary = summarise(results, spec.method)
    if foresight_of(spec) != "vf":  # the VF's, the default, is left unsaid as before
        summary["foresight"] = foresight_of(spec)
    atomic_write_json(out / "summary.json", summary)
    atomic_write_bytes(out / "summary.md", summary_markdown(summary).encode())
    return summary


def _episode_results(
    spec: PolicySpec, todo: list[tuple[Task, int]], step_slack: int, envs: EnvFactory, workers: int,
    envs_per_worker: int, where: dict,
) -> Iterator[EpisodeResult]:  # fmt: skip
    """The results of the ``todo`` episodes in their order: one job per episode, or per group of
    ``envs_per_worker`` consecutive episodes stepped together by one process."""
    if envs_per_worker == 1:
        yield from run_jobs(policy_episode, [(t, s, spec, step_slack, envs) for t, s in todo], workers,
                            f"eval {spec.method}", **where)  # fmt: skip
        return
    groups = [
        (todo[i : i + envs_per_worker], spec, step_slack, envs) for i in range(0, len(todo), envs_per_worker)
    ]
    desc = f"eval {spec.method} (groups of {envs_per_worker})"
    for results in run_jobs(policy_episodes, groups, workers, desc, **where):
        yield from results


def weights_hashes(spec: PolicySpec) -> dict[str, str]:
    """The SHA-256 of every weights file the method loads, by model kind (shipped ones when not given)."""
    return {
        kind: sha256_file(trained_checkpoint(getattr(spec, kind), kind))
        for kind in get_method(spec.method).models
    }


def _changed_settings(meta_path: Path, meta: dict) -> list[str]:
    """The settings in which a recorded evaluation differs from ``meta`` (settings added since it was made
    count as None, the value that keeps their old behaviour; a folder from before weights were hashed is
    trusted on its paths). Changed weights are named by kind: ``gctn weights (content ab12… → cd34…)``;
    a setting the spec left to its method whose default changed, by its values: ``turns (4 → 1)``. A
    folder from before settings were resolved is trusted on the spec's own values."""
    old = read_json(meta_path, "restore it or choose another --out")
    nested = ("weights", "resolved")
    changed = sorted(k for k in set(old) | set(meta) if k not in nested and old.get(k) != meta.get(k))
    was, now_resolved = old.get("resolved"), meta["resolved"]
    if was is not None:  # settings added since are new choices whose default keeps the old behaviour
        for key in sorted(set(was) & set(now_resolved)):
            if was[key] != now_resolved[key] and key not in changed:
                changed.append(f"{key} ({was[key]!r} → {now_resolved[key]!r})")
    before, now = old.get("weights"), meta["weights"]
    if before is not None:
        for kind in sorted(set(before) | set(now)):
            if before.get(kind) != now.get(kind):
                changed.append(
                    f"{kind} weights (content {_short(before.get(kind))} → {_short(now.get(kind))})"
                )
    return changed


def _short(digest: str | None) -> str:
    return f"{digest[:8]}…" if digest else "none"
