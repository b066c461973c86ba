"""The quick-start jobs: TVF-L with the shipped weights on the unseen tasks (the README's main job), and
the expert on every task with a picture gallery of the episodes."""

from __future__ import annotations

import json
from pathlib import Path

from tvf.evaluate.closed_loop import summarise
from tvf.evaluate.runner import EpisodeResult, policy_episode, run_episode
from tvf.experiment.pipeline import record_gif
from tvf.experiment.report import write_report
from tvf.io import atomic_write_bytes, atomic_write_json
from tvf.parallel import run_jobs
from tvf.policies import OraclePolicy, PolicySpec, policy_for
from tvf.seeds import episode_seeds
from tvf.sim.factory import sim_env
from tvf.tasks import Task, TaskTable, load_tasks
from tvf.viz.images import observation_panel, save_gif, save_png, side_by_side
from tvf.weights import provenance


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


def tvf_episode(task: Task, seed: int, gif: str | None, spec: PolicySpec) -> EpisodeResult:
    """One TVF-L episode; with ``gif`` its frames and imagined paths are recorded."""
    if gif:
        return record_gif(policy_for(spec), task, seed, Path(gif))
    return policy_episode(task, seed, spec)


def tvf_quickstart(
    out: Path, episodes: int = 2, seed: int = 1, workers: int = 2, tasks: str = "unseen",
    table: TaskTable | None = None, device: str = "auto",
) -> Path:  # fmt: skip
    """TVF-L (shipped lite weights) on ``tasks`` for ``episodes`` episodes each; writes the report."""
    spec = PolicySpec("tvf-large", device=device)
    policy_for(spec)  # fail fast when the shipped weights are missing
    chosen = (table or load_tasks()).resolve(tasks)
    jobs = [(t, s, str(out / "gifs" / f"{t.name}-0.gif") if i == 0 else None, spec)
            for t in chosen for i, s in enumerate(episode_seeds(seed, episodes))]  # fmt: skip
    results = [r.to_dict() for r in run_jobs(tvf_episode, jobs, workers, "TVF-L quick start")]
    summary = summarise(results, "tvf-large")
    folder = out / "eval" / "tvf-large"
    atomic_write_bytes(folder / "episodes.jsonl", "".join(json.dumps(r) + "\n" for r in results).encode())
    atomic_write_json(folder / "summary.json", summary)
    trained = provenance().get("experiment", {}).get("commands", ["(unknown)"])
    meta = {
        "job": "quick start: TVF-L with the shipped lite weights",
        "episodes": episodes,
        "seed_start": seed,
        "weights": "src/tvf/weights, trained by: " + "; ".join(trained),
    }
    gifs = {t.name: f"gifs/{t.name}-0.gif" for t in chosen}
    md, _ = write_report(out, {"tvf-large": summary}, meta, gifs)
    a = summary["average"]
    print(f"TVF-L: {a['success']:.0%} average success on {tasks} tasks ({a['episodes']} episodes); "
          f"report in {md} and {md.with_suffix('.html')}")  # fmt: skip
    return md
