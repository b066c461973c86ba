"""Commands about the simulated world: list tasks, run the oracle, render scenes."""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tvf.cli.common import at_least_one, check_output_dir, check_output_file
from tvf.errors import TvfError


@dataclass(frozen=True)
class TasksCmd:
    """List the tasks: name, split, number of blocks and step horizon."""

    json: bool = False
    """Print JSON instead of a table."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md), listed with the built-in ones."""

    def run(self) -> None:
        from tvf.tasks import load_tasks

        rows = [t.summary() for t in load_tasks(self.task_file).tasks]
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

    tasks: str = "all"
    """train | unseen | all | NAME[,NAME...] (see `tvf tasks`)."""
    episodes: int = 5
    """Episodes per task."""
    seed_start: int = 1
    """Episode i of each task uses seed SEED_START + 2i (the one seed rule of every command)."""
    workers: int = 1
    """Parallel processes (one PyBullet client each)."""
    step_slack: int = 0
    """Extra steps beyond one per block."""
    json: Path | None = None
    """Also write per-episode results and the per-task table to this JSON file."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md) that --tasks may name."""
    gui: bool = False
    """Watch in a PyBullet window (needs a display; one worker)."""

    def run(self) -> None:
        from tvf.evaluate.runner import policy_episode
        from tvf.io import atomic_write_json
        from tvf.parallel import run_jobs
        from tvf.policies import PolicySpec
        from tvf.seeds import episode_seeds
        from tvf.sim.factory import SimEnvFactory
        from tvf.tasks import load_tasks

        at_least_one(episodes=self.episodes, workers=self.workers)
        if self.gui and self.workers != 1:
            raise TvfError("--gui shows one window: use it with --workers 1")
        tasks = load_tasks(self.task_file).resolve(self.tasks)
        if self.json is not None:
            check_output_file(self.json, "--json")  # before any episode runs, not after
        spec, envs = PolicySpec("oracle"), SimEnvFactory(gui=self.gui)
        seeds = episode_seeds(self.seed_start, self.episodes)
        jobs = [(t, s, spec, self.step_slack, envs) for t in tasks for s in seeds]
        results = list(run_jobs(policy_episode, jobs, self.workers, "oracle"))
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
            atomic_write_json(self.json, {"tasks": table, "episodes": [r.to_dict() for r in results],
                                          "success": mean})  # fmt: skip


def render_scene(task, seed: int, out: Path, export_views: Path | None = None, sensor: str = "ideal",
                 depth_scale: float = 0.001) -> dict:  # fmt: skip
    """Write the initial and goal images (PNG + NPZ) and a perspective view of a task's scene; with
    ``export_views`` also the cameras' views of both, as a real rig records them (tvf.views; depth PNGs in
    units of ``depth_scale`` metres), and all of it through ``sensor`` (tvf.sim.sensors: noise, dropout,
    one camera, calibration errors)."""
    from tvf.io import atomic_write_bytes
    from tvf.sim.env import TvfEnv
    from tvf.sim.views import perspective_view
    from tvf.views import rgbh_bytes, write_views
    from tvf.viz.images import observation_panel, save_png

    env = TvfEnv(task, sensor=sensor)
    try:
        obs, info = env.reset(seed=seed)
        for name, image in (("initial", obs), ("goal", info["goal"])):
            save_png(out / f"{name}.png", observation_panel(image["color"], image["height"]))
            atomic_write_bytes(out / f"{name}.npz", rgbh_bytes(image["color"], image["height"]))
        save_png(out / "perspective.png", perspective_view(env.world))
        if export_views is not None:
            write_views(export_views / "scene", *env.sensed_views(), env.world.workspace, depth_scale)
            write_views(export_views / "goal", *env.goal_views, env.world.workspace, depth_scale)
        return {"task": env.task.name, "seed": seed, "blocks": env.task.n_blocks, "coverage": env.coverage}
    finally:
        env.close()


@dataclass(frozen=True)
class RenderCmd:
    """Render a task's scene: initial and goal images (PNG, and NPZ with arrays `color`, `height`)
    plus a perspective view; --export-views DIR also writes what a real rig would record (DIR/scene and
    DIR/goal: per camera a colour PNG, a 16-bit depth PNG in mm and a camera file; docs/real-robot.md)."""

    task: str
    """The task name (see `tvf tasks`)."""
    out: Path
    """Output directory."""
    seed: int = 0
    """Scene seed."""
    export_views: Path | None = None
    """Also write the cameras' views of the scene (DIR/scene) and of the finished structure (DIR/goal) as
    camera files + colour PNG + 16-bit depth PNG (mm), the input of `tvf plan`."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md) that --task may name."""
    sensor: str = "ideal"
    """The cameras (tvf.sim.sensors; docs/real-robot.md): ideal | one | d415 | d415-one | d415-one-calib |
    d415-one-calib-level (levelled on the table) | d415-one-goal2 (the goal from in front and behind) |
    d435-one. The images (and the exported views) are what that rig records."""
    depth_scale: float = 0.001
    """Metres per unit of the exported 16-bit depth PNGs: 0.001 (mm, ROS REP 118's default) or finer, e.g.
    0.0001 (a RealSense's finest setting; 16 bits then reach 6.5 m). Each camera file records it."""

    def run(self) -> None:
        from tvf.sim.sensors import get_sensor
        from tvf.tasks import load_tasks

        get_sensor(self.sensor)
        if not 1e-6 <= self.depth_scale <= 0.01:
            raise TvfError(f"--depth-scale is metres per unit of the depth PNGs, between 1e-6 and 0.01 "
                           f"(0.001: millimetres), got {self.depth_scale}")  # fmt: skip
        task = load_tasks(self.task_file).get(self.task)
        out = check_output_dir(self.out)
        export = None if self.export_views is None else check_output_dir(self.export_views, "--export-views")
        info = render_scene(task, self.seed, out, export, self.sensor, self.depth_scale)
        what = "initial/goal .png/.npz and perspective.png"
        cover = ", ".join(f"{k} {v:.1%}" for k, v in info["coverage"].items())
        print(f"wrote {what} for {info['task']} seed {self.seed} to {self.out} (sensor {self.sensor}; "
              f"pixels measured: {cover})")  # fmt: skip
        if export is not None:
            print(f"wrote the camera views of the scene and the goal to {export}/scene and {export}/goal")
