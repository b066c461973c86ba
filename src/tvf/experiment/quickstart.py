"""The quick-start jobs: GCTN and TVF-L with the shipped weights on the same episodes of the unseen tasks,
reported beside the shipped weights' recorded evaluation and the paper (the README's main job), and the
expert on every task with a picture gallery of the episodes."""

from __future__ import annotations

import json
import time
from pathlib import Path

from tvf import __version__
from tvf.evaluate.closed_loop import summarise
from tvf.evaluate.runner import EpisodeResult, policy_episode, run_episode
from tvf.experiment.pipeline import record_gif
from tvf.experiment.report import (
    plural,
    reported_record,
    shipped_entry,
    shipped_eval_text,
    weights_text,
    write_report,
)
from tvf.io import atomic_write_bytes, atomic_write_json
from tvf.parallel import run_jobs
from tvf.policies import OraclePolicy, PolicySpec, get_method, label, policy_for
from tvf.seeds import episode_seeds, seed_range
from tvf.sim.factory import sim_env
from tvf.tasks import Task, TaskTable, load_tasks
from tvf.viz.images import observation_panel, save_gif, save_png, side_by_side
from tvf.weights import provenance, shipped_name


def gallery_episode(task: Task, seed: int, out: str) -> EpisodeResult:
    """Run the expert once and write ``out/TASK/{episode.gif, initial.png, goal.png, final.png}``."""
    env = sim_env(task)
    seen: list[tuple[dict, dict]] = []
    result = run_episode(env, seed, OraclePolicy(env), task.horizon, stuck="oracle_stuck",
                         on_step=lambda obs, goal, _: seen.append((obs, goal)))  # fmt: skip
    goal = observation_panel(seen[0][1]["color"], seen[0][1]["height"])
    frames = [side_by_side(observation_panel(o["color"], o["height"]), goal) for o, _ in seen]
    folder = Path(out) / task.name
    save_gif(folder / "episode.gif", frames, fps=1.5)
    save_png(folder / "initial.png", frames[0])
    save_png(folder / "final.png", frames[-1])
    save_png(folder / "goal.png", goal)
    return result


def oracle_gallery(out: Path, seed: int = 1, workers: int = 2, tasks: TaskTable | None = None) -> list:
    """Run the expert once per task and write a gallery with an index (index.md, summary.json)."""
    table = tasks or load_tasks()
    jobs = [(t, seed, str(out)) for t in table.tasks]
    results = list(run_jobs(gallery_episode, jobs, workers, "oracle gallery"))
    lines = [
        "# tvf quick start: the expert on every task",
        "",
        "Each row links the episode as a GIF: current image (colour | height) beside the goal image.",
        "",
        "| task | split | blocks | success | progress | steps | episode |",
        "|---|---|---|---|---|---|---|",
    ]
    for t, r in zip(table.tasks, results, strict=True):
        lines.append(
            f"| {t.name} | {t.split} | {t.n_blocks} | {'yes' if r.success else 'no'} | {r.progress:.0%} "
            f"| {r.steps} | [gif]({t.name}/episode.gif) |"
        )
    atomic_write_bytes(out / "index.md", ("\n".join(lines) + "\n").encode())
    atomic_write_json(out / "summary.json", [r.to_dict() for r in results])
    ok = sum(r.success for r in results)
    print(f"expert succeeded on {ok}/{len(results)} tasks; gallery in {out}/index.md")
    return results


QUICKSTART_METHODS = ("gctn", "tvf-large")
"""The comparison the quick start shows: the GCTN alone and TVF-L planning with it."""
QUICKSTART_EPISODES = 5
"""Episodes per task: 40 per method on the 8 unseen tasks, a few minutes on 2 CPU cores."""


def method_episode(task: Task, seed: int, gif: str | None, spec: PolicySpec) -> EpisodeResult:
    """One episode of ``spec``; with ``gif`` it is recorded and written as a labelled GIF."""
    if gif:
        return record_gif(policy_for(spec), task, seed, Path(gif))
    return policy_episode(task, seed, spec)


def quickstart_meta(methods: list[str], chosen: list[Task], tasks: str, episodes: int, seed: int,
                    workers: int, seconds: float, shipped: dict) -> dict:  # fmt: skip
    """The report's header: what ran, on which episodes, with which weights, how long it took."""
    seeds = ", ".join(str(s) for s in episode_seeds(seed, min(episodes, 3))) + (", …" if episodes > 3 else "")
    names = " and ".join(label(m) for m in methods)
    planners = [f"{label(m)}: {planner_text(m)}" for m in methods if get_method(m).planner is not None]
    return {
        "run": f"{names} on the same {plural(len(chosen) * episodes, 'episode')}: {episodes} per task on "
        f"{task_words(tasks, chosen)}, seeds {seeds} ({seed_range(seed)} range)",
        "weights": weights_text(shipped)
        if shipped
        else f"{weight_names(methods)}; tvf {__version__} (no provenance record)",
        **({"planner": "; ".join(planners)} if planners else {}),
        "shipped evaluation": shipped_eval_text(shipped) + overlap_text(shipped, seed, episodes)
        if shipped
        else "none recorded",
        "wall time": f"{seconds / 60:.1f} min with {workers} worker{'s' if workers > 1 else ''}",
    }


def task_words(tasks: str, chosen: list[Task]) -> str:
    """``the 8 unseen tasks`` for a split, ``put-t, stack-stair`` for names."""
    if tasks in ("unseen", "train", "all"):
        return f"the {len(chosen)} {'training' if tasks == 'train' else tasks} tasks"
    return ", ".join(t.name for t in chosen)


def weight_names(methods: list[str]) -> str:
    """The shipped weights the methods load, by name: ``gctn-lite + vf-lite``."""
    kinds = dict.fromkeys(k for m in methods for k in get_method(m).models)
    return " + ".join(Path(shipped_name(k)).stem for k in kinds)


def overlap_text(shipped: dict, seed: int, episodes: int) -> str:
    """Says when this run's episodes are among those the shipped weights were evaluated on."""
    exp = shipped.get("experiment", {})
    if exp.get("seed_start") == seed and episodes <= exp.get("episodes", 0):
        return f"; this run's episodes are the first {episodes} per task of them"
    return ""


def planner_text(method: str) -> str:
    """``K=3, depth 3, nms proposals, 3 picks`` for a planner method."""
    p = get_method(method).planner
    picks = f", {p.pick_branches} picks" if p.pick_branches > 1 else ""
    return f"K={p.k}, depth {p.depth}, {p.proposals} proposals{picks}"


def run_quickstart(
    out: Path, episodes: int = QUICKSTART_EPISODES, seed: int = 1, workers: int = 2, tasks: str = "unseen",
    table: TaskTable | None = None, device: str = "auto", methods: tuple[str, ...] = QUICKSTART_METHODS,
) -> Path:  # fmt: skip
    """``methods`` (the shipped weights) on the same ``episodes`` episodes of each of ``tasks``, one GIF
    per method and task; writes the report with the shipped weights' and the paper's numbers beside."""
    start = time.perf_counter()
    specs = {m: PolicySpec(m, device=device) for m in methods}
    for spec in specs.values():
        policy_for(spec)  # fail fast when the shipped weights are missing
    chosen = (table or load_tasks()).resolve(tasks)
    gif = {(m, t.name): out / "gifs" / m / f"{t.name}-0.gif" for m in methods for t in chosen}
    seeds = episode_seeds(seed, episodes)
    slow_first = sorted(methods, key=lambda m: get_method(m).planner is None)  # cheap jobs fill in at the end
    jobs = [(t, s, str(gif[m, t.name]) if i == 0 else None, specs[m])
            for m in slow_first for t in chosen for i, s in enumerate(seeds)]  # fmt: skip
    done = [r.to_dict() for r in run_jobs(method_episode, jobs, workers, "quick start")]
    summaries = {}
    for m in methods:
        results = [r for r, job in zip(done, jobs, strict=True) if job[3].method == m]
        summaries[m] = summarise(results, m)
        folder = out / "eval" / m
        atomic_write_bytes(folder / "episodes.jsonl", "".join(json.dumps(r) + "\n" for r in results).encode())
        atomic_write_json(folder / "summary.json", summaries[m])
    shipped = reported_record(provenance())
    meta = quickstart_meta(list(methods), chosen, tasks, episodes, seed, workers, time.perf_counter() - start,
                           shipped)  # fmt: skip
    gifs = {t.name: {m: str(gif[m, t.name].relative_to(out)) for m in methods} for t in chosen}
    title = (
        f"tvf quick start: {' vs '.join(label(m) for m in methods)} on {task_words(tasks, chosen)} "
        f"({weight_names(list(methods))}, tvf {__version__})"
    )
    md, page = write_report(out, summaries, meta, gifs, title, shipped)
    print(quickstart_line(summaries, shipped, chosen) + f"; report in {page}")
    return md


def quickstart_line(summaries: dict[str, dict], shipped: dict, chosen: list[Task]) -> str:
    """``GCTN 45% vs TVF-L 62% average success (40 episodes each; the shipped weights' record on the
    unseen tasks: 44% vs 63%)``."""
    methods = list(summaries)
    ours = " vs ".join(f"{label(m)} {summaries[m]['average']['success']:.0%}" for m in methods)
    n = summaries[methods[0]]["average"]["episodes"]
    line = f"{ours} average success ({plural(n, 'episode')} each"
    splits = {t.split for t in chosen}
    split = splits.pop() if len(splits) == 1 else "all"
    recorded = [shipped_entry(shipped, m, split) for m in methods]
    if all(recorded):
        words = {"train": "training tasks", "unseen": "unseen tasks", "all": "tasks"}[split]
        line += f"; the shipped weights' record on the {words}: " + " vs ".join(
            f"{e['success']:.0%}" for e in recorded
        )
    return line + ")"
