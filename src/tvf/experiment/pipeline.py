"""`tvf experiment`: the paper's experiment as one resumable pipeline.

Stages (each one skips or resumes what is already in EXP):

1. ``data``: demonstrations, train split (``demos`` per training task) and test split (validation,
   foresight evaluation) into ``EXP/data`` (or an existing dataset given with ``--data``);
2. ``train``: GCTN into ``EXP/gctn`` and VF into ``EXP/vf`` (training runs resume from their last checkpoint);
3. ``eval-vf``: prediction quality into ``EXP/eval-vf``;
4. ``eval``: closed loop for every method into ``EXP/eval/METHOD`` (episodes.jsonl resumes);
5. ``gifs``: one TVF-L episode per unseen task beside its imagined best paths, ``EXP/gifs/TASK.gif``;
6. ``report``: ``EXP/report.md``, ``EXP/report.html`` and ``EXP/success.png``;
7. ``weights``: the trained models without optimiser state plus ``provenance.json`` in ``EXP/weights``
   (``make reproduce`` copies them to the shipped weights).
"""

from __future__ import annotations

import json
import sys
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from tvf.data.generation import GenerationPlan, generate
from tvf.errors import TvfError
from tvf.evaluate.closed_loop import evaluate
from tvf.evaluate.foresight import evaluate_foresight
from tvf.evaluate.recording import record_episode
from tvf.experiment.report import group_average, write_report
from tvf.io import atomic_write_bytes, atomic_write_json
from tvf.models.checkpoint import load_model, save_checkpoint, trained_checkpoint
from tvf.policies import METHODS, PolicySpec, make_policy
from tvf.runs import RunDir
from tvf.sim.factory import sim_env
from tvf.tasks import TaskTable, load_tasks
from tvf.train.registry import MODELS, recipe
from tvf.train.trainer import TrainConfig, train
from tvf.viz.plan import episode_gif
from tvf.weights import PROVENANCE, WEIGHTS_DIR, shipped_name

STAGES = ("data", "train", "eval-vf", "eval", "gifs", "report", "weights")
RECIPE_FLAGS = {f"{kind}_{field}": (kind, field) for kind in MODELS for field in ("steps", "batch", "lr")}
RECIPE_FLAGS |= {"gctn_schedule": ("gctn", "schedule"), "gctn_warmup": ("gctn", "warmup")}
"""Experiment flags that override a field of a model kind's recipe (tvf.train.registry)."""


@dataclass(frozen=True)
class ExperimentConfig:
    """Everything an experiment depends on; stored in EXP/experiment.json and checked on resume."""

    out: Path
    """Experiment folder (data, runs, evaluations, report); re-running the same command resumes."""
    demos: int = 10
    """Demonstrations per training task (the paper: 1, 10, 100, 1000)."""
    preset: str = "lite"
    """Model size: lite (2-core CPU) | paper (the reference widths; a GPU job) | smoke (tests)."""
    data: Path | None = None
    """An existing dataset root made by `tvf demos` (default: EXP/data, generated here)."""
    test_demos: int = 5
    """Test-split episodes per task (validation and foresight evaluation)."""
    train_tasks: str = "train"
    """Tasks the models learn from."""
    tasks: str = "all"
    """Tasks evaluated in closed loop: train | unseen | all | NAME[,NAME...]."""
    methods: str = "oracle,gctn,tvf-small,tvf-large"
    """Methods evaluated, comma-separated."""
    episodes: int = 20
    """Closed-loop episodes per task and method (the paper: 20)."""
    seed: int = 0
    """Training seed (demo subset, initialisation, batches)."""
    seed_start: int = 1
    """Evaluation episode i uses seed seed_start + 2i."""
    step_slack: int = 0
    """Extra steps beyond one per block (0 = the paper's protocol)."""
    gctn_steps: int | None = None
    """GCTN optimiser steps (default: the preset's, lite 14000)."""
    gctn_batch: int | None = None
    """GCTN batch (default: the preset's, lite 2)."""
    gctn_lr: float | None = None
    """GCTN Adam (peak) learning rate (default: the preset's, lite 2e-4)."""
    gctn_schedule: str | None = None
    """GCTN learning-rate schedule, constant | cosine (default: the preset's, lite cosine)."""
    gctn_warmup: int | None = None
    """GCTN warm-up steps of the cosine schedule (default: the preset's, lite 500)."""
    vf_steps: int | None = None
    """VF optimiser steps (default: the preset's, lite 3000)."""
    vf_batch: int | None = None
    """VF batch (default: the preset's, lite 8)."""
    vf_lr: float | None = None
    """VF Adam learning rate (default: the preset's, 1e-4)."""
    workers: int = 2
    """Parallel processes for data generation and evaluation."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md) that --tasks and --train-tasks may name."""
    device: str = "auto"
    """auto | cpu | cuda: where the models train and run (auto: CUDA when present)."""
    gifs: int = 1
    """TVF-L episodes recorded as GIFs per unseen task (0: none)."""
    stages: str = ",".join(STAGES)
    """Stages to run, comma-separated, in pipeline order: data,train,eval-vf,eval,gifs,report,weights."""
    ship: bool = False
    """After the weights stage, copy EXP/weights over the package's shipped weights (make reproduce)."""

    def resolved(self) -> ExperimentConfig:
        """Fill the training schedules from the preset's recipes (tvf.train.registry)."""
        return replace(self, **{
            flag: getattr(recipe(kind, self.preset), field)
            for flag, (kind, field) in RECIPE_FLAGS.items() if getattr(self, flag) is None
        })  # fmt: skip

    def task_table(self) -> TaskTable:
        return load_tasks(self.task_file)

    @property
    def data_root(self) -> Path:
        return Path(self.data) if self.data is not None else self.out / "data"

    def method_list(self) -> list[str]:
        names = [m.strip() for m in self.methods.split(",") if m.strip()]
        bad = [m for m in names if m not in METHODS]  # the method registry
        if bad or not names:
            raise TvfError(
                f"unknown method(s) {', '.join(bad) or '(none)'}; choose from {', '.join(METHODS)}"
            )
        return names

    def stage_list(self) -> list[str]:
        names = [s.strip() for s in self.stages.split(",") if s.strip()]
        bad = [s for s in names if s not in STAGES]
        if bad:
            raise TvfError(f"unknown stage(s) {', '.join(bad)}; choose from {', '.join(STAGES)}")
        return names


def _say(message: str) -> None:
    print(f"[experiment] {message}", flush=True)


def _read_recorded(path: Path) -> dict:
    """EXP/experiment.json as a dict ({} when there is none); a corrupt file is a clear error."""
    if not path.exists():
        return {}
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise TvfError(f"{path} is not valid JSON; restore it or choose another --out") from None


def _record_config(cfg: ExperimentConfig) -> None:
    """Write EXP/experiment.json, refusing to mix two different experiments in one folder."""
    path = cfg.out / "experiment.json"
    keep = {k: v for k, v in asdict(cfg).items() if k not in ("workers", "stages", "ship", "device")}
    if keep["task_file"] is None:
        keep.pop("task_file")  # folders made before the flag existed resume
    keep = json.loads(json.dumps(keep, default=str))
    recorded = _read_recorded(path)
    changed = sorted(k for k in keep if recorded and recorded.get(k) != keep[k])
    if changed:
        raise TvfError(
            f"{cfg.out} holds an experiment with other {', '.join(changed)}; "
            "use the same flags or another --out"
        )
    commands = recorded.get("commands", [])
    commands.append(" ".join(["tvf", *sys.argv[1:]]) if sys.argv else "tvf experiment")
    cfg.out.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, json.dumps({**keep, "commands": commands}, indent=1).encode())


def stage_data(cfg: ExperimentConfig) -> None:
    table = cfg.task_table()
    train = tuple(t.name for t in table.resolve(cfg.train_tasks))
    both = tuple(dict.fromkeys([*train, *(t.name for t in table.resolve(cfg.tasks))]))
    for split, tasks, n in (("train", train, cfg.demos), ("test", both, cfg.test_demos)):
        report = generate(GenerationPlan(tasks, split, n, cfg.data_root), cfg.workers, tasks=table)
        if report.short:
            raise TvfError(f"too few successful demonstrations in {cfg.data_root / split}: {report.short}")


def train_config(cfg: ExperimentConfig, kind: str) -> TrainConfig:
    """The `tvf train` configuration of one model: the preset's recipe with the experiment's overrides."""
    base = recipe(kind, cfg.preset)
    fields = {field: getattr(cfg, flag) for flag, (k, field) in RECIPE_FLAGS.items() if k == kind}
    steps = fields.get("steps", base.steps)
    return TrainConfig(
        data=cfg.data_root, out=cfg.out / kind, demos=cfg.demos, preset=cfg.preset,
        schedule=fields.get("schedule", base.schedule), warmup=fields.get("warmup", base.warmup),
        steps=steps, batch=fields["batch"], lr=fields["lr"], seed=cfg.seed, tasks=cfg.train_tasks,
        task_file=cfg.task_file, val_every=max(1, steps // 10), checkpoint_every=max(1, steps // 10),
        log_every=max(1, min(25, steps)), resume=True, device=cfg.device,
    )  # fmt: skip


def stage_train(cfg: ExperimentConfig) -> None:
    for kind, spec in MODELS.items():
        tc = train_config(cfg, kind)
        _say(f"training {kind}: {tc.steps} steps, batch {tc.batch}, lr {tc.lr:g} ({tc.schedule}) -> {tc.out}")
        train(tc, spec.job(tc, spec.sampler_class))


def stage_eval_vf(cfg: ExperimentConfig) -> None:
    evaluate_foresight(cfg.out / "vf", cfg.data_root, cfg.out / "eval-vf", max_episodes=cfg.test_demos,
                       tasks=cfg.task_table())  # fmt: skip


def method_spec(cfg: ExperimentConfig, method: str) -> PolicySpec:
    """The experiment's own models under ``method``."""
    return PolicySpec(method, str(cfg.out / "gctn"), str(cfg.out / "vf"), device=cfg.device)


def stage_eval(cfg: ExperimentConfig) -> None:
    tasks = cfg.task_table().resolve(cfg.tasks)
    for method in cfg.method_list():
        _say(f"evaluating {method}: {len(tasks)} tasks x {cfg.episodes} episodes")
        spec = method_spec(cfg, method)
        evaluate(spec, tasks, cfg.episodes, cfg.seed_start, cfg.workers, cfg.out / "eval" / method,
                 cfg.step_slack)  # fmt: skip


def record_gif(policy, task, seed: int, path: Path, step_slack: int = 0):
    """Run one recorded episode in the simulator and write its GIF; returns the episode result."""
    result, steps = record_episode(policy, sim_env(task), seed, task.horizon + step_slack)
    episode_gif(path, steps)
    return result


def stage_gifs(cfg: ExperimentConfig) -> None:
    if cfg.gifs < 1:
        return
    policy = make_policy(method_spec(cfg, "tvf-large"))
    for task in (t for t in cfg.task_table().resolve(cfg.tasks) if t.split == "unseen"):
        for i in range(cfg.gifs):
            path = cfg.out / "gifs" / f"{task.name}-{i}.gif"
            if not path.exists():
                result = record_gif(policy, task, cfg.seed_start + 2 * i, path, cfg.step_slack)
                _say(f"{path}: success {result.success}, progress {result.progress:.0%}")


def _summaries(cfg: ExperimentConfig) -> dict[str, dict]:
    out = {}
    for method in cfg.method_list():
        path = cfg.out / "eval" / method / "summary.json"
        if path.exists():
            out[method] = json.loads(path.read_text())
    return out


def _meta(cfg: ExperimentConfig) -> dict:
    meta = {k: getattr(cfg, k) for k in ("preset", "demos", "episodes", "seed", "seed_start", "step_slack")}
    meta["training"] = (
        f"GCTN {cfg.gctn_steps} steps x batch {cfg.gctn_batch} (lr {cfg.gctn_lr:g} {cfg.gctn_schedule}); "
        f"VF {cfg.vf_steps} steps x batch {cfg.vf_batch} (lr {cfg.vf_lr:g})"
    )
    commands = _read_recorded(cfg.out / "experiment.json").get("commands", [])
    if commands:
        meta["commands"] = "; ".join(commands)
    return meta


def stage_report(cfg: ExperimentConfig) -> tuple[Path, Path]:
    gifs = {}
    for gif in sorted((cfg.out / "gifs").glob("*-0.gif")):
        gifs[gif.name[: -len("-0.gif")]] = str(gif.relative_to(cfg.out))
    return write_report(cfg.out, _summaries(cfg), _meta(cfg), gifs)


def _group_results(summary: dict, table: TaskTable) -> dict:
    """A method's average success over all tasks, the unseen ones and the training ones."""
    out = {"all": summary["average"]}
    for split in ("unseen", "train"):
        average = group_average(summary, [t.name for t in table.resolve(split)])
        if average is not None:
            out[split] = average
    return out


def stage_weights(cfg: ExperimentConfig) -> Path:
    """Model-only copies of the trained checkpoints plus a provenance record, in EXP/weights."""
    out = cfg.out / "weights"
    record: dict = {"experiment": _read_recorded(cfg.out / "experiment.json"), "models": {}}
    for kind in MODELS:
        run = RunDir(cfg.out / kind)
        model, ckpt = load_model(trained_checkpoint(run.root, kind), kind)
        run_config = run.read_config()
        name = shipped_name(kind, cfg.preset)
        save_checkpoint(out / name, model, None, ckpt.step, ckpt.config, ckpt.extra)
        record["models"][kind] = {
            "file": name, "step": ckpt.step, "preset": cfg.preset,
            "data_fingerprint": run_config.get("data_fingerprint"), "seed": run_config.get("seed"),
            "episodes": run_config.get("episodes"), "train": run_config.get("train"),
            "parameters": sum(p.numel() for p in model.parameters()), "validation": run.last_validation(),
        }  # fmt: skip
    table = cfg.task_table()
    record["results"] = {m: _group_results(summary, table) for m, summary in _summaries(cfg).items()}
    atomic_write_json(out / PROVENANCE, record)
    return out


def ship_weights(exp_weights: Path, target: Path, preset: str = "lite") -> None:
    """Copy an experiment's weights folder (models of ``preset``) into the package's shipped weights."""
    for name in (*(shipped_name(kind, preset) for kind in MODELS), PROVENANCE):
        if not (exp_weights / name).exists():
            raise TvfError(f"{exp_weights / name} is missing; run the experiment's weights stage first")
        atomic_write_bytes(target / name, (exp_weights / name).read_bytes())


RUNNERS = {
    "data": stage_data, "train": stage_train, "eval-vf": stage_eval_vf, "eval": stage_eval,
    "gifs": stage_gifs, "report": stage_report, "weights": stage_weights,
}  # fmt: skip


def run_experiment(cfg: ExperimentConfig) -> Path:
    """Run the selected stages in order; returns EXP/report.md (when the report stage ran)."""
    cfg = cfg.resolved()
    stages = cfg.stage_list()
    cfg.method_list()
    _record_config(cfg)
    for stage in stages:
        _say(f"stage {stage}")
        RUNNERS[stage](cfg)
    if cfg.ship:
        ship_weights(cfg.out / "weights", WEIGHTS_DIR, cfg.preset)
        _say(f"shipped {cfg.out / 'weights'} to {WEIGHTS_DIR}")
    return cfg.out / "report.md"
