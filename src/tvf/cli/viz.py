"""`tvf viz gctn|plan`: pictures of one decision on a task's first scene."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro

from tvf.cli.common import PlannerFlags, check_output_dir
from tvf.errors import TvfError


def _path(p: Path | None) -> str | None:
    return str(p) if p else None


def first_scene(task_file: Path | None, task: str, seed: int):
    """The environment of ``task`` reset to ``seed``, its first observation and its goal."""
    from tvf.sim.factory import sim_env
    from tvf.tasks import load_tasks

    env = sim_env(load_tasks(task_file).get(task))
    obs, info = env.reset(seed=seed)
    return env, obs, info["goal"]


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
    """GCTN run folder (its checkpoints/last.pt), a .pt or .safetensors file; default: the shipped weights."""
    seed: int = 1
    """Scene seed (odd seeds below 1000001 are the validation range)."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md) that --task may name."""
    device: str = "auto"
    """auto | cpu | cuda: where the model runs."""

    def run(self) -> None:
        from tvf.device import pick_device
        from tvf.io import atomic_path, atomic_write_bytes
        from tvf.models.checkpoint import load_trained
        from tvf.viz.gctn import decision_maps, gctn_figure

        model = load_trained(_path(self.gctn), "gctn", pick_device(self.device))
        _, obs, goal = first_scene(self.task_file, self.task, self.seed)
        out = check_output_dir(self.out)
        d = decision_maps(model, obs, goal)
        atomic_write_bytes(out / "gctn_decision.png", gctn_figure(obs, goal, d, model.preset.n_rotations))
        with atomic_path(out / "gctn_maps.npz") as tmp, tmp.open("wb") as f:
            np.savez_compressed(f, pick=d["pick_prob"], place=d["place_prob"])
        print(f"wrote {out / 'gctn_decision.png'} and gctn_maps.npz")


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
    """Scene seed (odd seeds below 1000001 are the validation range)."""
    method: str = "tvf-large"
    """tvf-small | tvf-large."""
    k: int | None = None
    """Place proposals per node (default: the method's)."""
    depth: int | None = None
    """Search depth (default: the method's)."""
    planner: tyro.conf.OmitArgPrefixes[PlannerFlags] = PlannerFlags()
    """The models and the planner's settings (default: the method's)."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md) that --task may name."""
    device: str = "auto"
    """auto | cpu | cuda: where the models run."""

    def run(self) -> None:
        from tvf.io import atomic_write_bytes, atomic_write_json
        from tvf.policies import PLANNER_METHODS, make_policy
        from tvf.viz.plan import decision_figure, plan_record

        if self.method not in PLANNER_METHODS:
            raise TvfError(f"--method must be one of {', '.join(PLANNER_METHODS)}, got {self.method!r}")
        spec = self.planner.spec(self.method, self.k, self.depth, self.device)
        policy = make_policy(spec)
        _, obs, goal = first_scene(self.task_file, self.task, self.seed)
        out = check_output_dir(self.out)
        policy.keep_images = True
        policy.act(obs, goal)
        plan = policy.last_plan
        atomic_write_bytes(out / "plan.png", decision_figure(obs, goal, plan, policy.search.n_rotations))
        atomic_write_json(out / "plan.json", plan_record(plan))
        print(f"wrote {out / 'plan.png'} and plan.json")


@dataclass(frozen=True)
class VizCmd:
    """Pictures of decisions: `tvf viz gctn ...` (heat maps) or `tvf viz plan ...` (a TVF search)."""

    command: tyro.conf.OmitArgPrefixes[
        Annotated[VizGctn, tyro.conf.subcommand("gctn")] | Annotated[VizPlan, tyro.conf.subcommand("plan")]
    ]
    """What to draw."""

    def run(self) -> None:
        self.command.run()
