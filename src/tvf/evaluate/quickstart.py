"""The quick-start jobs: TVF-L with the shipped weights on the unseen tasks (the README's main job), and
the expert on every task with a picture gallery of the episodes."""

from __future__ import annotations

import json
from pathlib import Path

from tvf.evaluate.runner import EpisodeResult, cached_env, run_episode, run_jobs
from tvf.viz.images import atomic_write_bytes, observation_panel, save_gif, save_png, side_by_side


def gallery_episode(task: str, seed: int, out: str) -> EpisodeResult:
    """Run the expert once and write ``out/TASK/{episode.gif, initial.png, goal.png, final.png}``."""
    env = cached_env(task)
    seen: list[tuple[dict, dict]] = []
    result = run_episode(env, seed, lambda obs, goal: env.oracle_action(), env.task.horizon,
                         stuck="oracle_stuck", on_obs=lambda obs, goal: seen.append((obs, goal)))  # fmt: skip
    goal = observation_panel(seen[0][1]["color"], seen[0][1]["height"])
    frames = [side_by_side(observation_panel(o["color"], o["height"]), goal) for o, _ in seen]
    folder = Path(out) / task
    save_gif(folder / "episode.gif", frames, fps=1.5)
    save_png(folder / "initial.png", frames[0])
    save_png(folder / "final.png", frames[-1])
    save_png(folder / "goal.png", goal)
    return result


def oracle_gallery(out: Path, seed: int = 1, workers: int = 2) -> list[EpisodeResult]:
    """Run the expert once per task and write a gallery with an index (index.md, summary.json)."""
    from tvf.tasks import all_tasks

    tasks = list(all_tasks().values())
    jobs = [(t.name, seed, str(out)) for t in tasks]
    results = list(run_jobs(gallery_episode, jobs, workers, "oracle gallery"))
    lines = [
        "# tvf quick start: the expert on every task",
        "",
        "Each row links the episode as a GIF: current image (colour | height) beside the goal image.",
        "",
        "| task | split | blocks | success | progress | steps | episode |",
        "|---|---|---|---|---|---|---|",
    ]
    for t, r in zip(tasks, results, strict=True):
        lines.append(
            f"| {t.name} | {t.split} | {t.n_blocks} | {'yes' if r.success else 'no'} | {r.progress:.0%} "
            f"| {r.steps} | [gif]({t.name}/episode.gif) |"
        )
    atomic_write_bytes(out / "index.md", ("\n".join(lines) + "\n").encode())
    atomic_write_bytes(out / "summary.json", json.dumps([r.to_dict() for r in results], indent=1).encode())
    ok = sum(r.success for r in results)
    print(f"expert succeeded on {ok}/{len(results)} tasks; gallery in {out}/index.md")
    return results


def tvf_episode(task: str, seed: int, gif: str | None) -> EpisodeResult:
    """One TVF-L episode with the shipped weights; with ``gif`` its frames and imagined paths are recorded."""
    from tvf.evaluate.closed_loop import PolicySpec, cached_policy, policy_episode
    from tvf.viz.plan import record_episode

    spec = PolicySpec("tvf-large")
    if gif:
        return record_episode(cached_policy(spec), task, seed, Path(gif))
    return policy_episode(task, seed, spec)


def tvf_quickstart(
    out: Path, episodes: int = 2, seed: int = 1, workers: int = 2, tasks: str = "unseen"
) -> Path:
    """TVF-L (shipped lite weights) on ``tasks`` for ``episodes`` episodes each; writes the report."""
    from tvf.evaluate.closed_loop import PolicySpec, cached_policy, summarise
    from tvf.evaluate.report import write_report
    from tvf.tasks import resolve_tasks
    from tvf.weights import provenance

    cached_policy(PolicySpec("tvf-large"))  # fail fast when the shipped weights are missing
    names = [t.name for t in resolve_tasks(tasks)]
    jobs = [(t, seed + 2 * i, str(out / "gifs" / f"{t}-0.gif") if i == 0 else None)
            for t in names for i in range(episodes)]  # fmt: skip
    results = [r.to_dict() for r in run_jobs(tvf_episode, jobs, workers, "TVF-L quick start")]
    summary = summarise(results, "tvf-large")
    folder = out / "eval" / "tvf-large"
    atomic_write_bytes(folder / "episodes.jsonl", "".join(json.dumps(r) + "\n" for r in results).encode())
    atomic_write_bytes(folder / "summary.json", json.dumps(summary, indent=1).encode())
    trained = provenance().get("experiment", {}).get("commands", ["(unknown)"])
    meta = {
        "job": "quick start: TVF-L with the shipped lite weights",
        "episodes": episodes,
        "seed_start": seed,
        "weights": "src/tvf/weights, trained by: " + "; ".join(trained),
    }
    gifs = {t: f"gifs/{t}-0.gif" for t in names}
    md, _ = write_report(out, {"tvf-large": summary}, meta, gifs)
    a = summary["average"]
    print(f"TVF-L: {a['success']:.0%} average success on {tasks} tasks ({a['episodes']} episodes); "
          f"report in {md} and {md.with_suffix('.html')}")  # fmt: skip
    return md
