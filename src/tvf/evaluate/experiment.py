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

from tvf.errors import TvfError
from tvf.viz.images import atomic_write_bytes

STAGES = ("data", "train", "eval-vf", "eval", "gifs", "report", "weights")

TRAINING_DEFAULTS: dict[str, dict[str, object]] = {
    # lite: the GCTN fits 45 minutes and the VF 7 on the 2-core CPU (docs/results.md)
    "lite": dict(gctn_steps=14000, gctn_batch=2, gctn_lr=2e-4, gctn_schedule="cosine", gctn_warmup=500,
                 vf_steps=3000, vf_batch=8, vf_lr=1e-4),
    # paper: the reference's schedules (batch 1, constant learning rate)
    "paper": dict(gctn_steps=40000, gctn_batch=1, gctn_lr=1e-4, gctn_schedule="constant", gctn_warmup=0,
                  vf_steps=60000, vf_batch=1, vf_lr=1e-4),
    "smoke": dict(gctn_steps=2, gctn_batch=2, gctn_lr=1e-3, gctn_schedule="constant", gctn_warmup=0,
                  vf_steps=2, vf_batch=2, vf_lr=1e-3),
}  # fmt: skip


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
    gifs: int = 1
    """TVF-L episodes recorded as GIFs per unseen task (0: none)."""
    stages: str = ",".join(STAGES)
    """Stages to run, comma-separated, in pipeline order: data,train,eval-vf,eval,gifs,report,weights."""
    ship: bool = False
    """After the weights stage, copy EXP/weights over the package's shipped weights (make reproduce)."""

    def resolved(self) -> ExperimentConfig:
        """Fill the training schedule from the preset's defaults."""
        if self.preset not in TRAINING_DEFAULTS:
            raise TvfError(f"unknown preset {self.preset!r}; choose one of {', '.join(TRAINING_DEFAULTS)}")
        defaults = TRAINING_DEFAULTS[self.preset]
        return replace(self, **{k: v for k, v in defaults.items() if getattr(self, k) is None})

    @property
    def data_root(self) -> Path:
        return Path(self.data) if self.data is not None else self.out / "data"

    def method_list(self) -> list[str]:
        from tvf.evaluate.closed_loop import METHODS

        names = [m.strip() for m in self.methods.split(",") if m.strip()]
        bad = [m for m in names if m not in METHODS]
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
    keep = {k: v for k, v in asdict(cfg).items() if k not in ("workers", "stages", "ship")}
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
    from tvf.data.generation import GenerationPlan, generate
    from tvf.tasks import resolve_tasks

    train = tuple(t.name for t in resolve_tasks(cfg.train_tasks))
    both = tuple(dict.fromkeys([*train, *(t.name for t in resolve_tasks(cfg.tasks))]))
    for split, tasks, n in (("train", train, cfg.demos), ("test", both, cfg.test_demos)):
        report = generate(GenerationPlan(tasks, split, n, cfg.data_root), cfg.workers)
        if report.short:
            raise TvfError(f"too few successful demonstrations in {cfg.data_root / split}: {report.short}")


def _train_config(cfg: ExperimentConfig, kind: str):
    from tvf.train.trainer import TrainConfig

    if kind == "gctn":
        steps, batch, lr = cfg.gctn_steps, cfg.gctn_batch, cfg.gctn_lr
        schedule = {"schedule": cfg.gctn_schedule, "warmup": cfg.gctn_warmup}
    else:
        steps, batch, lr, schedule = cfg.vf_steps, cfg.vf_batch, cfg.vf_lr, {}
    every = max(1, steps // 10)
    return TrainConfig(
        data=cfg.data_root, out=cfg.out / kind, demos=cfg.demos, preset=cfg.preset, steps=steps, batch=batch,
        lr=lr, seed=cfg.seed, tasks=cfg.train_tasks, val_every=every, checkpoint_every=every,
        log_every=max(1, min(25, steps)), resume=True, **schedule,
    )  # fmt: skip


def stage_train(cfg: ExperimentConfig) -> None:
    from tvf.train.jobs import gctn_job, vf_job
    from tvf.train.trainer import train

    for kind, job in (("gctn", gctn_job), ("vf", vf_job)):
        tc = _train_config(cfg, kind)
        _say(f"training {kind}: {tc.steps} steps, batch {tc.batch}, lr {tc.lr:g} ({tc.schedule}) -> {tc.out}")
        train(tc, job(tc))


def stage_eval_vf(cfg: ExperimentConfig) -> None:
    from tvf.evaluate.foresight import evaluate_foresight

    evaluate_foresight(cfg.out / "vf", cfg.data_root, cfg.out / "eval-vf", max_episodes=cfg.test_demos)


def method_spec(cfg: ExperimentConfig, method: str):
    from tvf.evaluate.closed_loop import PolicySpec

    return PolicySpec(method, str(cfg.out / "gctn"), str(cfg.out / "vf"), step_slack=cfg.step_slack)


def stage_eval(cfg: ExperimentConfig) -> None:
    from tvf.evaluate.closed_loop import evaluate
    from tvf.tasks import resolve_tasks

    names = [t.name for t in resolve_tasks(cfg.tasks)]
    for method in cfg.method_list():
        _say(f"evaluating {method}: {len(names)} tasks x {cfg.episodes} episodes")
        spec = method_spec(cfg, method)
        evaluate(spec, names, cfg.episodes, cfg.seed_start, cfg.workers, cfg.out / "eval" / method)


def stage_gifs(cfg: ExperimentConfig) -> None:
    from tvf.evaluate.closed_loop import make_policy
    from tvf.tasks import resolve_tasks
    from tvf.viz.plan import record_episode

    if cfg.gifs < 1:
        return
    policy = make_policy(method_spec(cfg, "tvf-large"))
    selected = {t.name for t in resolve_tasks(cfg.tasks)}
    for task in (t.name for t in resolve_tasks("unseen") if t.name in selected):
        for i in range(cfg.gifs):
            path = cfg.out / "gifs" / f"{task}-{i}.gif"
            if not path.exists():
                result = record_episode(policy, task, cfg.seed_start + 2 * i, path, step_slack=cfg.step_slack)
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
    from tvf.evaluate.report import write_report

    gifs = {}
    for gif in sorted((cfg.out / "gifs").glob("*-0.gif")):
        gifs[gif.name[: -len("-0.gif")]] = str(gif.relative_to(cfg.out))
    return write_report(cfg.out, _summaries(cfg), _meta(cfg), gifs)


def _last_val(run: Path) -> dict:
    metrics = run / "metrics.jsonl"
    vals = (
        [json.loads(ln) for ln in metrics.read_text().splitlines() if '"val"' in ln]
        if metrics.exists()
        else []
    )
    return vals[-1] if vals else {}


def _group_results(summary: dict) -> dict:
    """A method's average success over all tasks, the unseen ones and the training ones."""
    from tvf.evaluate.report import group_average
    from tvf.tasks import resolve_tasks

    out = {"all": summary["average"]}
    for split in ("unseen", "train"):
        average = group_average(summary, [t.name for t in resolve_tasks(split)])
        if average is not None:
            out[split] = average
    return out


def stage_weights(cfg: ExperimentConfig) -> Path:
    """Model-only copies of the trained checkpoints plus a provenance record, in EXP/weights."""
    from tvf.evaluate.policies import resolve_checkpoint
    from tvf.models.checkpoint import load_model, save_checkpoint
    from tvf.weights import FILES

    out = cfg.out / "weights"
    record: dict = {"experiment": _read_recorded(cfg.out / "experiment.json"), "models": {}}
    for kind in ("gctn", "vf"):
        model, ckpt = load_model(resolve_checkpoint(cfg.out / kind, kind), kind)
        run_config = json.loads((cfg.out / kind / "config.json").read_text())
        save_checkpoint(out / FILES[kind], model, None, ckpt.step, ckpt.config, ckpt.extra)
        record["models"][kind] = {
            "file": FILES[kind], "step": ckpt.step, "preset": cfg.preset,
            "data_fingerprint": run_config.get("data_fingerprint"), "seed": run_config.get("seed"),
            "episodes": run_config.get("episodes"), "train": run_config.get("train"),
            "parameters": sum(p.numel() for p in model.parameters()), "validation": _last_val(cfg.out / kind),
        }  # fmt: skip
    record["results"] = {method: _group_results(summary) for method, summary in _summaries(cfg).items()}
    atomic_write_bytes(out / "provenance.json", json.dumps(record, indent=1, default=str).encode())
    return out


def ship_weights(exp_weights: Path, target: Path) -> None:
    """Copy an experiment's weights folder into the package's shipped weights."""
    for name in ("gctn-lite.pt", "vf-lite.pt", "provenance.json"):
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
        from tvf.weights import WEIGHTS_DIR

        ship_weights(cfg.out / "weights", WEIGHTS_DIR)
        _say(f"shipped {cfg.out / 'weights'} to {WEIGHTS_DIR}")
    return cfg.out / "report.md"
