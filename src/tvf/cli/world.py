"""Commands about the simulated world: list tasks, run the oracle, render scenes."""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro

from tvf.errors import TvfError


def use_task_file(task_file: Path | None) -> None:
    """Register the tasks of a user's YAML/JSON file so they can be named like built-in ones."""
    if task_file is not None:
        from tvf.tasks import load_task_file, register_tasks

        register_tasks(load_task_file(task_file))


def check_output_dir(path: Path) -> Path:
    """Create ``path`` or fail with one clear line if it cannot be written."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".tvf-write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise TvfError(
            f"cannot write to output directory {path}: {exc.strerror}; choose another --out"
        ) from None
    return path


@dataclass(frozen=True)
class TasksCmd:
    """List the tasks: name, split, number of blocks and step horizon."""

    json: bool = False
    """Print JSON instead of a table."""
    task_file: Path | None = None
    """A YAML or JSON task file (schema: docs/tasks.md) whose tasks are listed with the built-in ones."""

    def run(self) -> None:
        from tvf.tasks import all_tasks

        use_task_file(self.task_file)
        rows = [t.summary() for t in all_tasks().values()]
        if self.json:
            print(json.dumps(rows, indent=2))
            return
        print(f"{'task':<20} {'split':<7} {'blocks':>6} {'horizon':>7} {'layers':>6}  base")
        for r in rows:
            name, split, blocks, horizon = r["name"], r["split"], r["blocks"], r["horizon"]
            print(f"{name:<20} {split:<7} {blocks:>6} {horizon:>7} {r['layers']:>6}  {r['base']}")


@dataclass(frozen=True)
class OracleCmd:
    """Run the scripted expert and report its success per task (the ceiling for learned methods)."""

    task: str = "all"
    """A task name, several separated by commas, or train | unseen | all."""
    episodes: int = 5
    """Episodes per task."""
    seed: int = 0
    """Episode i of each task uses seed `seed + i`."""
    workers: int = 1
    """Parallel processes (one PyBullet client each)."""
    step_slack: int = 0
    """Extra steps beyond one per block."""
    json: Path | None = None
    """Also write per-episode results and the per-task table to this JSON file."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md)."""
    gui: bool = False
    """Watch in a PyBullet window (needs a display; one worker)."""

    def run(self) -> None:
        from tvf.evaluate.runner import oracle_episode, run_jobs
        from tvf.tasks import resolve_tasks
        from tvf.viz.images import atomic_write_bytes

        use_task_file(self.task_file)
        if self.episodes < 1 or self.workers < 1:
            raise TvfError("--episodes and --workers must be at least 1")
        if self.gui and self.workers != 1:
            raise TvfError("--gui shows one window: use it with --workers 1")
        tasks = resolve_tasks(self.task)
        seeds = [self.seed + i for i in range(self.episodes)]
        jobs = [(t.name, seed, self.step_slack, self.gui) for t in tasks for seed in seeds]
        results = list(run_jobs(oracle_episode, jobs, self.workers, "oracle", self.task_file))
        per_task: dict[str, list] = defaultdict(list)
        for r in results:
            per_task[r.task].append(r)
        table = []
        for name, rs in per_task.items():
            failures = [
                {"seed": r.seed, "progress": r.progress, "primitives": r.primitives}
                for r in rs
                if not r.success
            ]
            table.append({
                "task": name, "episodes": len(rs), "success": float(np.mean([r.success for r in rs])),
                "progress": float(np.mean([r.progress for r in rs])), "failures": failures,
            })  # fmt: skip
        print(f"{'task':<20} {'success':>8} {'progress':>9}  failed seeds")
        for row in table:
            seeds = ",".join(str(f["seed"]) for f in row["failures"]) or "-"
            print(f"{row['task']:<20} {row['success']:>8.0%} {row['progress']:>9.0%}  {seeds}")
        mean = float(np.mean([r.success for r in results]))
        print(f"{'all':<20} {mean:>8.0%}")
        if self.json is not None:
            doc = {"tasks": table, "episodes": [r.to_dict() for r in results], "success": mean}
            atomic_write_bytes(self.json, json.dumps(doc, indent=1).encode())


def render_scene(task: str, seed: int, out: Path) -> dict:
    """Write the initial and goal images (PNG + NPZ) and a perspective view of a task's scene."""
    import io

    from tvf.sim.env import TvfEnv
    from tvf.sim.views import perspective_view
    from tvf.viz.images import atomic_write_bytes, observation_panel, save_png

    env = TvfEnv(task)
    try:
        obs, info = env.reset(seed=seed)
        for name, image in (("initial", obs), ("goal", info["goal"])):
            save_png(out / f"{name}.png", observation_panel(image["color"], image["height"]))
            buf = io.BytesIO()
            np.savez_compressed(buf, color=image["color"], height=image["height"])
            atomic_write_bytes(out / f"{name}.npz", buf.getvalue())
        save_png(out / "perspective.png", perspective_view(env.world))
        return {"task": env.task.name, "seed": seed, "blocks": env.task.n_blocks}
    finally:
        env.close()


@dataclass(frozen=True)
class RenderCmd:
    """Render a task's scene: initial and goal images (PNG, and NPZ with arrays `color`, `height`)
    plus a perspective view."""

    task: str
    """The task name (see `tvf tasks`)."""
    out: Path
    """Output directory."""
    seed: int = 0
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md)."""

    def run(self) -> None:
        from tvf.tasks import get_task

        use_task_file(self.task_file)
        get_task(self.task)
        info = render_scene(self.task, self.seed, check_output_dir(self.out))
        what = "initial/goal .png/.npz and perspective.png"
        print(f"wrote {what} for {info['task']} seed {self.seed} to {self.out}")


@dataclass(frozen=True)
class QuickstartCmd:
    """The README's main job: TVF-L with the shipped lite weights on every unseen task, a report with GIFs.

    Writes OUT/report.md, OUT/report.html, OUT/success.png and OUT/gifs/TASK-0.gif (the real episode beside
    the imagined best path at each step). --expert instead runs the scripted expert once on every task.
    """

    out: Path = Path("out/quickstart")
    """Output directory."""
    episodes: int = 2
    """Episodes per unseen task."""
    seed: int = 1
    """Episode i uses seed SEED + 2i."""
    workers: int = 2
    """Parallel processes."""
    tasks: str = "unseen"
    """Tasks to run: unseen | train | all | NAME[,NAME...]."""
    expert: bool = False
    """Run the expert on every task and write a gallery (index.md) instead."""

    def run(self) -> None:
        from tvf.evaluate.quickstart import oracle_gallery, tvf_quickstart

        if self.episodes < 1 or self.workers < 1:
            raise TvfError("--episodes and --workers must be at least 1")
        if self.expert:
            oracle_gallery(check_output_dir(self.out), self.seed, self.workers)
        else:
            tvf_quickstart(check_output_dir(self.out), self.episodes, self.seed, self.workers, self.tasks)


@dataclass(frozen=True)
class EvalCmd:
    """Evaluate a method in closed loop on test seeds; writes episodes.jsonl, summary.json, summary.md.

    Methods: oracle (the expert, the ceiling), gctn (greedy GCTN), tvf-small (K=2, depth 1) and tvf-large
    (K=3, depth 3). Without --gctn / --vf the shipped lite weights are used.
    Example: tvf eval --method tvf-large --tasks unseen --episodes 20 --workers 2 --out eval/tvf-large
    """

    method: str = "gctn"
    """oracle | gctn | tvf-small | tvf-large."""
    out: Path = Path("out/eval")
    """Output directory (re-running the same command resumes)."""
    gctn: Path | None = None
    """GCTN run directory (uses checkpoints/last.pt) or checkpoint file; default: the shipped weights."""
    vf: Path | None = None
    """VF run directory or checkpoint file (TVF methods); default: the shipped weights."""
    k: int | None = None
    """TVF: place proposals per node (default: the method's, 2 or 3)."""
    depth: int | None = None
    """TVF: search depth (default: the method's, 1 or 3)."""
    tasks: str = "unseen"
    """train | unseen | all | NAME[,NAME...]."""
    episodes: int = 20
    """Episodes per task."""
    seed_start: int = 1
    """Episode i uses seed seed_start + 2i (odd seeds: the test split's)."""
    workers: int = 1
    """Parallel processes (one simulator and one model copy each)."""
    step_slack: int = 0
    """Extra steps beyond one per block (0 = the paper's protocol)."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md)."""

    def spec(self):
        from tvf.evaluate.closed_loop import PolicySpec

        path = lambda p: str(p) if p else None  # noqa: E731
        return PolicySpec(self.method, path(self.gctn), path(self.vf), self.k, self.depth, self.step_slack)

    def run(self) -> None:
        from tvf.evaluate.closed_loop import cached_policy, evaluate, summary_markdown
        from tvf.tasks import resolve_tasks

        use_task_file(self.task_file)
        if self.episodes < 1 or self.workers < 1:
            raise TvfError("--episodes and --workers must be at least 1")
        names = [t.name for t in resolve_tasks(self.tasks)]
        spec = self.spec()
        cached_policy(spec)  # fail fast on a bad method or checkpoint, before any worker starts
        check_output_dir(self.out)
        tf = str(self.task_file) if self.task_file else None
        summary = evaluate(spec, names, self.episodes, self.seed_start, self.workers, self.out, tf)
        print(summary_markdown(summary))


@dataclass(frozen=True)
class VizGctn:
    """Pick and place heat maps of a trained GCTN over a task's first image, with the chosen action.

    Example: tvf viz gctn --gctn runs/gctn --task put-t --seed 1 --out out/viz
    """

    task: str
    """The task whose scene is drawn (see `tvf tasks`)."""
    out: Path
    """Output directory (gctn_decision.png, gctn_maps.npz)."""
    gctn: Path | None = None
    """GCTN run directory (uses checkpoints/last.pt) or checkpoint file; default: the shipped weights."""
    seed: int = 1
    """Scene seed (odd seeds are the test split's)."""

    def run(self) -> None:
        from tvf.tasks import get_task
        from tvf.viz.gctn import visualise_gctn

        get_task(self.task)
        path = visualise_gctn(self.gctn, self.task, self.seed, check_output_dir(self.out))
        print(f"wrote {path} and gctn_maps.npz")


@dataclass(frozen=True)
class VizPlan:
    """One TVF decision: the proposals on the place map, every imagined node with its score, the best path.

    Example: tvf viz plan --task stack-stair --seed 1 --out out/plan   (shipped weights unless --gctn/--vf)
    """

    task: str
    """The task whose first scene is planned (see `tvf tasks`)."""
    out: Path
    """Output directory (plan.png, plan.json)."""
    seed: int = 1
    """Scene seed (odd seeds are the test split's)."""
    gctn: Path | None = None
    """GCTN run directory or checkpoint (default: the shipped weights)."""
    vf: Path | None = None
    """VF run directory or checkpoint (default: the shipped weights)."""
    method: str = "tvf-large"
    """tvf-small | tvf-large."""
    k: int | None = None
    """Place proposals per node (default: the method's)."""
    depth: int | None = None
    """Search depth (default: the method's)."""

    def run(self) -> None:
        from tvf.evaluate.closed_loop import PolicySpec, make_policy
        from tvf.tasks import get_task
        from tvf.viz.plan import visualise_plan

        get_task(self.task)
        if self.method not in ("tvf-small", "tvf-large"):
            raise TvfError(f"--method must be tvf-small or tvf-large, got {self.method!r}")
        path = lambda p: str(p) if p else None  # noqa: E731
        policy = make_policy(PolicySpec(self.method, path(self.gctn), path(self.vf), self.k, self.depth))
        out = visualise_plan(policy, self.task, self.seed, check_output_dir(self.out))
        print(f"wrote {out} and plan.json")


@dataclass(frozen=True)
class VizCmd:
    """Pictures of decisions: `tvf viz gctn ...` (heat maps) or `tvf viz plan ...` (a TVF search)."""

    command: tyro.conf.OmitArgPrefixes[
        Annotated[VizGctn, tyro.conf.subcommand("gctn")] | Annotated[VizPlan, tyro.conf.subcommand("plan")]
    ]
    """What to draw."""

    def run(self) -> None:
        self.command.run()


@dataclass(frozen=True)
class EvalVfCmd:
    """Prediction quality of a visual-foresight model on a test split, beside the copy and paste baselines.

    Writes metrics.json, metrics.md and predictions.png (input, action, prediction, truth, error);
    with --horizon H > 1 also multi-step rollout metrics (the model fed its own predictions for 1..H
    steps) in metrics.json's `horizons` section, metrics.md and horizons.png.
    Example: tvf eval-vf --vf runs/vf --data data/demos --out eval/vf --horizon 3
    """

    vf: Path
    """VF run directory (uses checkpoints/last.pt) or checkpoint file."""
    data: Path
    """Dataset root with a test/ split, or a test split folder."""
    out: Path = Path("out/eval-vf")
    episodes: int = 20
    """Test episodes per task (the reference used the first 20)."""
    horizon: int = 1
    """Rollout steps fed the model's own output, from every step of each episode (1 = one-step only)."""

    def run(self) -> None:
        from tvf.evaluate.foresight import check_horizon, evaluate_foresight, metrics_markdown

        check_horizon(self.horizon)
        out = check_output_dir(self.out)
        summary = evaluate_foresight(self.vf, self.data, out, self.episodes, horizon=self.horizon)
        print(metrics_markdown(summary))
