"""`tvf eval` (closed-loop success of a method) and `tvf eval-vf` (foresight prediction quality)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import tyro

from tvf.cli.common import PlannerFlags, at_least_one, check_output_dir
from tvf.seeds import TEST_SEED_START


@dataclass(frozen=True)
class EvalCmd:
    """Evaluate a method in closed loop; writes episodes.jsonl, summary.json, summary.md (resumable).

    Methods (the method registry): oracle (the expert, the ceiling), gctn (greedy GCTN), tvf-small (K=2,
    depth 1, the paper's proposals) and tvf-large (K=3, depth 3, NMS proposals over 3 picks, its first
    actions above --root-alpha 0.001; the paper's rule: --proposals kmeans --pick-branches 1 --root-alpha
    0.01). gctn-paper, tvf-small-paper and tvf-large-paper are the three with the paper's rules: no turns
    averaged, nothing read from the height maps, the paper's search (K-means proposals, no tie band).
    gctn-no-image-rules, tvf-small-no-image-rules and tvf-large-no-image-rules are ours reading nothing
    from the height maps: our turns and our search only. Without --gctn / --vf the shipped lite weights
    are used.
    Seeds: the test range by default (never used for a choice); --seed-start 1 is the validation range.
    Example: tvf eval --method tvf-large --tasks unseen --episodes 20 --workers 2 --out eval/tvf-large
    """

    method: str = "gctn"
    """oracle | gctn | tvf-small | tvf-large | gctn-paper | tvf-small-paper | tvf-large-paper |
    gctn-no-image-rules | tvf-small-no-image-rules | tvf-large-no-image-rules."""
    out: Path = Path("out/eval")
    """Output directory (re-running the same command resumes)."""
    k: int | None = None
    """TVF: place proposals per node (default: the method's, 2 or 3)."""
    depth: int | None = None
    """TVF: search depth (default: the method's, 1 or 3)."""
    planner: tyro.conf.OmitArgPrefixes[PlannerFlags] = PlannerFlags()
    """The models and the planner's settings (default: the method's)."""
    tasks: str = "unseen"
    """train | unseen | all | NAME[,NAME...] (see `tvf tasks`)."""
    episodes: int = 20
    """Episodes per task."""
    seed_start: int = TEST_SEED_START
    """Episode i uses seed SEED_START + 2i: 1000001 = the test range, 1 = the validation range."""
    workers: int = 1
    """Parallel processes (one simulator and one model copy each); with --backend ray, Ray tasks at once."""
    envs_per_worker: int = 1
    """Simulators each process steps in lock-step, their decisions batched into shared model calls (pays on
    a GPU; the episodes are those of one at a time; docs/planner.md)."""
    backend: Literal["local", "ray"] = "local"
    """Where the episodes run: local (a process pool on this host) | ray (Ray tasks on a local Ray
    instance of --workers CPUs, or on the cluster at --address; pip install 'tvf[ray]'; docs/parallel.md).
    The results are the same bytes either way."""
    address: str | None = None
    """With --backend ray: the running Ray cluster to use, HOST:6379 (default: start a local instance)."""
    step_slack: int = 0
    """Extra steps beyond one per block (0 = the paper's protocol)."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md) that --tasks may name."""
    device: str = "auto"
    """auto | cpu | cuda: where the models run (auto: CUDA when present)."""
    env: str = "sim"
    """The world: sim (the PyBullet simulator) or MODULE:NAME, a picklable factory task -> Env
    (tvf.envs.Env; docs/architecture.md), e.g. a real robot or a noisy-camera wrapper."""
    restart: bool = False
    """Drop the episodes already in --out and run them again (a resume is refused when the settings or the
    weights files' content changed; this starts over instead)."""

    def spec(self):
        return self.planner.spec(self.method, self.k, self.depth, self.device)

    def run(self) -> None:
        from tvf.evaluate.closed_loop import evaluate, summary_markdown
        from tvf.evaluate.runner import check_envs_per_worker, env_factory
        from tvf.policies import check_policy
        from tvf.tasks import load_tasks

        at_least_one(episodes=self.episodes, workers=self.workers)
        tasks = load_tasks(self.task_file).resolve(self.tasks)
        envs = env_factory(self.env)
        check_envs_per_worker(self.envs_per_worker, envs)
        spec = self.spec()
        check_policy(spec)
        check_output_dir(self.out)
        summary = evaluate(
            spec,
            tasks,
            self.episodes,
            self.seed_start,
            self.workers,
            self.out,
            self.step_slack,
            envs,
            self.restart,
            self.envs_per_worker,
            self.backend,
            self.address,
        )
        print(summary_markdown(summary))


@dataclass(frozen=True)
class EvalVfCmd:
    """Prediction quality of a visual-foresight model on a test split, beside the copy, paste and rigid
    baselines (rigid: the picked block moved on the height map, the search's --foresight rigid;
    rigid-falls: also tipped off where it would not rest) and, with --latent RUN, the latent-dynamics
    baseline of `tvf train latent`.

    Writes metrics.json, metrics.md and predictions.png (input, action, prediction, truth, error);
    with --horizon H > 1 also multi-step rollout metrics (the model fed its own predictions for 1..H
    steps) in metrics.json's `horizons` section, metrics.md and horizons.png.
    Example: tvf eval-vf --vf runs/vf --data data/demos --out eval/vf --horizon 3
    """

    data: Path
    """Dataset root with a test/ split, or a test split folder."""
    vf: Path | None = None
    """VF run folder (its checkpoints/last.pt), a .pt or .safetensors file; default: the shipped weights."""
    latent: Path | None = None
    """A latent-dynamics run (`tvf train latent`), .pt or .safetensors file to score beside the VF as method
    `latent`; default: none."""
    out: Path = Path("out/eval-vf")
    episodes: int = 20
    """Test episodes per task (the reference used the first 20)."""
    horizon: int = 1
    """Rollout steps fed the model's own output, from every step of each episode (1 = one-step only)."""
    task_file: Path | None = None
    """A YAML or JSON file of the extra tasks a dataset made with --task-file holds."""
    device: str = "auto"
    """auto | cpu | cuda: where the models run (auto: CUDA when present)."""
    snap_heights: bool = False
    """Score the VF as the search with --snap-heights True uses it: every height it moves set to the
    nearest level a surface rests at, at every rollout step (the baselines are unchanged)."""

    def run(self) -> None:
        from tvf.device import pick_device
        from tvf.evaluate.foresight import check_horizon, evaluate_foresight, metrics_markdown
        from tvf.tasks import load_tasks

        at_least_one(episodes=self.episodes)
        check_horizon(self.horizon)
        device = str(pick_device(self.device))
        summary = evaluate_foresight(self.vf, self.data, self.out, self.episodes, horizon=self.horizon,
                                     tasks=load_tasks(self.task_file), device=device,
                                     latent_checkpoint=self.latent,
                                     snap_heights=self.snap_heights)  # fmt: skip
        print(metrics_markdown(summary))


@dataclass(frozen=True)
class AblateCmd:
    """The K x depth ablation: closed-loop success of one planner at every branching K and depth, with the
    same models and episodes; writes OUT/k{K}-d{D}/ (one resumable evaluation per cell), ablation.json,
    ablation.md and the heat map ablation.png. The paper's grid is K 2,3 x depth 1,2,3,4 at 10 demos.
    Example: tvf ablate --k 2,3 --depth 1,2,3,4 --tasks unseen --episodes 20 --workers 2 --out eval/ablation
    """

    out: Path = Path("out/ablation")
    """Output directory (re-running the same command resumes every cell)."""
    k: str = "2,3"
    """Place proposals per node, comma-separated."""
    depth: str = "1,2,3,4"
    """Search depths, comma-separated."""
    method: str = "tvf-large"
    """tvf-small | tvf-large (or either with -paper or -no-image-rules): the planner whose other settings
    (proposal rule, picks) every cell keeps."""
    planner: tyro.conf.OmitArgPrefixes[PlannerFlags] = PlannerFlags()
    """The models and the planner's other settings (default: the method's; picks at most K)."""
    tasks: str = "unseen"
    """train | unseen | all | NAME[,NAME...]."""
    episodes: int = 20
    """Episodes per task and cell."""
    seed_start: int = TEST_SEED_START
    """Episode i uses seed SEED_START + 2i: 1000001 = the test range, 1 = the validation range."""
    workers: int = 1
    """Parallel processes."""
    step_slack: int = 0
    """Extra steps beyond one per block (0 = the paper's protocol)."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks that --tasks may name."""
    device: str = "auto"
    """auto | cpu | cuda."""

    def run(self) -> None:
        from tvf.experiment.ablation import ablation_cells, parse_grid, run_ablation
        from tvf.policies import check_policy
        from tvf.tasks import load_tasks

        at_least_one(episodes=self.episodes, workers=self.workers)
        ks, depths = parse_grid(self.k, "k"), parse_grid(self.depth, "depth")
        tasks = load_tasks(self.task_file).resolve(self.tasks)
        spec = self.planner.spec(self.method, device=self.device)
        ablation_cells(spec, ks, depths)
        check_policy(spec)
        check_output_dir(self.out)
        run_ablation(spec, ks, depths, tasks, self.episodes, self.seed_start, self.workers, self.out,
                     self.step_slack)  # fmt: skip
        print((self.out / "ablation.md").read_text())


@dataclass(frozen=True)
class CompareCmd:
    """Compare evaluations on the episodes they share (matched by task and seed): each run's successes
    per task with a Wilson 95% interval, and each later run against the first as episodes it wins and
    loses, with the exact two-sided sign test (episodes both finish or both lose are left out). Reads the
    episodes.jsonl of tvf eval folders, tvf ablate cells or an experiment's evaluations.
    Example: tvf compare eval/tvf-large eval/tvf-large-d1 --labels "depth 3,depth 1"
    """

    folders: tyro.conf.Positional[tuple[Path, ...]]
    """Evaluation folders; the first is the baseline the others are paired against."""
    labels: str | None = None
    """Comma-separated names, one per folder (default: each folder's method and the flags it set)."""
    json: Path | None = None
    """Also write the numbers to this JSON file."""

    def run(self) -> None:
        from tvf.evaluate.compare import compare, comparison_markdown, read_runs
        from tvf.io import atomic_write_json

        labels = [s.strip() for s in self.labels.split(",")] if self.labels is not None else None
        result = compare(read_runs(list(self.folders), labels))
        if self.json is not None:
            atomic_write_json(self.json, result)
        print(comparison_markdown(result), end="")
