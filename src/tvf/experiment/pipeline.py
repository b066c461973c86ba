"""`tvf experiment`: the paper's experiment as one resumable pipeline.

Stages (each one skips or resumes what is already in EXP):

1. ``data``: demonstrations, train split (``demos`` per training task) and test split (validation,
   foresight evaluation) into ``EXP/data`` (or an existing dataset given with ``--data``);
2. ``train``: GCTN into ``EXP/gctn`` and VF into ``EXP/vf`` (training runs resume from their last checkpoint);
   with ``--vf-tune`` the VF is then fine-tuned into ``EXP/vf-tuned``, the VF of every later stage;
3. ``eval-vf``: prediction quality into ``EXP/eval-vf``;
4. ``eval``: closed loop for every method into ``EXP/eval/METHOD`` (episodes.jsonl resumes);
5. ``gifs``: one TVF-L episode per unseen task beside its imagined best paths, ``EXP/gifs/TASK.gif``;
6. ``report``: ``EXP/report.md``, ``EXP/report.html`` and ``EXP/success.png``;
7. ``weights``: the trained models as safetensors + JSON config, ``provenance.json`` (with every file's
   SHA-256) and the model card ``README.md`` in ``EXP/weights`` (``--ship``, as in ``make reproduce``,
   copies them to the shipped weights; tvf.experiment.shipping).
"""

from __future__ import annotations

import json
import sys
from dataclasses import asdict, replace
from pathlib import Path

from tvf.data.generation import GenerationPlan, generate
from tvf.device import pick_device
from tvf.errors import StaleError, TvfError
from tvf.evaluate.closed_loop import evaluate
from tvf.evaluate.foresight import evaluate_foresight
from tvf.evaluate.recording import RecordedEpisode, record_episode
from tvf.experiment.config import NOT_RECORDED, RECIPE_FLAGS, ExperimentConfig, merged_methods
from tvf.experiment.cost import costed, hours, stage_costs
from tvf.experiment.report import evaluated_methods, plural, write_report
from tvf.experiment.shipping import group_results, ship_model, ship_weights, write_model_card
from tvf.io import atomic_write_json, check_output_dir, read_json
from tvf.parallel import check_backend, import_ray
from tvf.planning.rigid import RIGID_FORESIGHTS
from tvf.policies import PolicySpec, label, make_policy, split_variant
from tvf.sim.factory import sim_env
from tvf.train.registry import MODELS, RECIPE_FIELDS, vf_tune, with_recipe
from tvf.train.trainer import TrainConfig, check_config, train
from tvf.viz.recorded import episode_gif
from tvf.weights import PROVENANCE, WEIGHTS_DIR


def _say(message: str) -> None:
    print(f"[experiment] {message}", flush=True)


def _read_recorded(path: Path) -> dict:
    """EXP/experiment.json as a dict ({} when there is none); a corrupt file is a clear error."""
    return read_json(path, "restore it or choose another --out", {})


def _record_config(cfg: ExperimentConfig) -> None:
    """Write EXP/experiment.json, refusing to mix two different experiments in one folder."""
    path = cfg.out / "experiment.json"
    keep = {k: v for k, v in asdict(cfg).items() if k not in (*NOT_RECORDED, "restart")}
    keep = json.loads(json.dumps(keep, default=str))
    recorded = _read_recorded(path)
    # a folder made before a flag existed lacks it: it resumes when the flag keeps its (resolved) default
    defaults = json.loads(json.dumps(asdict(ExperimentConfig(out=cfg.out, preset=cfg.preset).resolved()),
                                     default=str))  # fmt: skip
    # the folder's own path is recorded, not compared: a moved (or copied) experiment resumes; other
    # methods add to it
    keep["methods"] = merged_methods(recorded.get("methods"), keep["methods"])
    compared = [k for k in keep if recorded and k not in ("out", "methods")]
    changed = sorted(k for k in compared if recorded.get(k, defaults.get(k)) != keep[k])
    if changed:
        raise TvfError(
            f"{cfg.out} holds an experiment with other {', '.join(changed)}; "
            "use the same flags or another --out"
        )
    commands = recorded.get("commands", [])
    commands.append(" ".join(["tvf", *sys.argv[1:]]) if sys.argv else "tvf experiment")
    atomic_write_json(path, {**keep, "commands": commands})


def data_plans(cfg: ExperimentConfig) -> list[GenerationPlan]:
    """What the data stage generates: ``demos`` train-split episodes of each training task and
    ``test_demos`` test-split episodes of every training and evaluated task, under ``cfg.data_root``."""
    table = cfg.task_table()
    train = tuple(t.name for t in table.resolve(cfg.train_tasks))
    both = tuple(dict.fromkeys([*train, *(t.name for t in table.resolve(cfg.tasks))]))
    return [GenerationPlan(train, "train", cfg.demos, cfg.data_root),
            GenerationPlan(both, "test", cfg.test_demos, cfg.data_root)]  # fmt: skip


def stage_data(cfg: ExperimentConfig) -> None:
    table = cfg.task_table()
    for plan in data_plans(cfg):
        report = generate(plan, cfg.workers, tasks=table, backend=cfg.backend, address=cfg.address)
        if report.short:
            raise TvfError(f"too few successful demonstrations in {plan.folder}: {report.short}")


def train_config(cfg: ExperimentConfig, kind: str) -> TrainConfig:
    """The `tvf train` configuration of one model: the preset's recipe with the experiment's overrides."""
    overrides = {field: getattr(cfg, flag) for flag, (k, field) in RECIPE_FLAGS.items() if k == kind}
    tc = with_recipe(TrainConfig(
        data=cfg.data_root, out=cfg.out / kind, demos=cfg.demos, preset=cfg.preset, seed=cfg.seed,
        tasks=cfg.train_tasks, task_file=cfg.task_file, resume=True, restart=cfg.restart, device=cfg.device,
        wandb=cfg.wandb, gctn_kernels=cfg.gctn_kernels if kind == "gctn" else None,
        gctn_width=cfg.gctn_width if kind == "gctn" else None,
        hindsight=cfg.gctn_hindsight if kind == "gctn" else 0.0,
        mirror=cfg.gctn_mirror if kind == "gctn" else 0.0, **overrides,
    ), kind)  # fmt: skip
    return _with_intervals(tc)


def _with_intervals(tc: TrainConfig) -> TrainConfig:
    """An experiment's run validates and checkpoints ten times over its steps and logs every 25."""
    every = max(1, tc.steps // 10)
    return replace(tc, val_every=every, checkpoint_every=every, log_every=max(1, min(25, tc.steps)))


def tune_config(cfg: ExperimentConfig) -> TrainConfig:
    """The VF's second phase (``--vf-tune``): the preset's tuning recipe and head, from EXP/vf's weights,
    into EXP/vf-tuned."""
    phase, head = vf_tune(cfg.preset)
    tc = replace(train_config(cfg, "vf"), out=cfg.out / "vf-tuned", init=cfg.out / "vf", vf_head=head,
                 **{f: getattr(phase, f) for f in RECIPE_FIELDS})  # fmt: skip
    return _with_intervals(tc)


def model_dir(cfg: ExperimentConfig, kind: str) -> Path:
    """The run folder of the model every stage after training uses (the tuned VF with ``--vf-tune``)."""
    return cfg.out / ("vf-tuned" if kind == "vf" and cfg.vf_tune else kind)


def stage_train(cfg: ExperimentConfig) -> None:
    runs = [(kind, train_config(cfg, kind)) for kind in MODELS]
    if cfg.vf_tune:
        runs.append(("vf", tune_config(cfg)))
    for kind, tc in runs:
        spec = MODELS[kind]
        _say(f"training {kind}: {tc.steps} steps, batch {tc.batch}, lr {tc.lr:g} ({tc.schedule}) -> {tc.out}")
        train(tc, spec.job(tc, spec.sampler_class))


def stage_eval_vf(cfg: ExperimentConfig) -> None:
    device = str(pick_device(cfg.device))
    evaluate_foresight(model_dir(cfg, "vf"), cfg.data_root, cfg.out / "eval-vf", max_episodes=cfg.test_demos,
                       horizon=cfg.vf_horizon, tasks=cfg.task_table(), device=device)  # fmt: skip


def method_spec(cfg: ExperimentConfig, method: str) -> PolicySpec:
    """The experiment's own models under ``method`` (``METHOD+FORESIGHT``: its search scored by that
    foresight; a rigid one reads no VF)."""
    base, foresight = split_variant(method)
    vf = None if foresight in RIGID_FORESIGHTS else str(model_dir(cfg, "vf"))
    return PolicySpec(base, str(model_dir(cfg, "gctn")), vf, device=cfg.device, foresight=foresight)


def stage_eval(cfg: ExperimentConfig) -> None:
    tasks = cfg.task_table().resolve(cfg.tasks)
    for method in cfg.method_list():
        _say(f"evaluating {method}: {len(tasks)} tasks x {cfg.episodes} episodes")
        spec, out = method_spec(cfg, method), cfg.out / "eval" / method
        run = (spec, tasks, cfg.episodes, cfg.seed_start, cfg.workers, out, cfg.step_slack)
        where = {"envs_per_worker": cfg.envs_per_worker, "backend": cfg.backend, "address": cfg.address}
        try:
            evaluate(*run, **where)
        except StaleError:  # weights retrained (the data changed) or settings changed under it
            if not cfg.restart:
                raise
            _say(f"{out}: its weights or settings changed; evaluating {method} again (--restart)")
            evaluate(*run, restart=True, **where)


def record_gif(policy, task, seed: int, path: Path, step_slack: int = 0):
    """Run one recorded episode in the simulator and write its labelled GIF; returns the episode result."""
    horizon = task.horizon + step_slack
    result, steps = record_episode(policy, sim_env(task), seed, horizon)
    episode = RecordedEpisode(task.name, seed, label(policy.name), task.n_blocks, horizon, result.success)
    episode_gif(path, episode, steps)
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
    """The finished evaluations of every method evaluated in the folder, this run's and others' (a later
    command with other --methods adds columns to the report, it does not take any away)."""
    evals = cfg.out / "eval"
    return {m: json.loads((evals / m / "summary.json").read_text()) for m in evaluated_methods(evals)}


def _meta(cfg: ExperimentConfig) -> dict:
    meta = {k: getattr(cfg, k) for k in ("preset", "demos", "episodes", "seed", "seed_start", "step_slack")}
    meta["training"] = (
        f"GCTN {cfg.gctn_steps} steps x batch {cfg.gctn_batch} (lr {cfg.gctn_lr:g} {cfg.gctn_schedule}); "
        f"VF {cfg.vf_steps} steps x batch {cfg.vf_batch} (lr {cfg.vf_lr:g})"
    )
    commands = _read_recorded(cfg.out / "experiment.json").get("commands", [])
    if commands:
        meta["commands"] = "; ".join(commands)
    costs = stage_costs(cfg.out)  # the report stage's own run is recorded after it
    if costs:
        each = ", ".join(f"{stage} {hours(c['cpu_s'])}" for stage, c in costs.items())
        cpu, wall = (hours(sum(c[key] for c in costs.values())) for key in ("cpu_s", "wall_s"))
        meta["cost so far"] = f"{cpu} CPU h in {wall} h of wall time ({each}; cost.jsonl)"
    return meta


def stage_report(cfg: ExperimentConfig) -> tuple[Path, Path]:
    gifs = {}
    for gif in sorted((cfg.out / "gifs").glob("*-0.gif")):
        gifs[gif.name[: -len("-0.gif")]] = {"tvf-large": str(gif.relative_to(cfg.out))}
    title = f"tvf experiment: {cfg.preset} models, {plural(cfg.demos, 'demo')} per training task"
    return write_report(cfg.out, _summaries(cfg), _meta(cfg), gifs, title)


def stage_weights(cfg: ExperimentConfig) -> Path:
    """The trained models as shipped weights, their provenance (experiment, models, results) and model
    card, in EXP/weights."""
    out = cfg.out / "weights"
    atomic_write_json(out / PROVENANCE, {"experiment": _read_recorded(cfg.out / "experiment.json")})
    for kind in MODELS:
        ship_model(model_dir(cfg, kind), kind, out)
    record = read_json(out / PROVENANCE, "run the weights stage again")
    table = cfg.task_table()
    summaries = _summaries(cfg)
    record["results"] = {m: group_results(summary, table) for m, summary in summaries.items()}
    record["task_results"] = {m: summary["tasks"] for m, summary in summaries.items()}
    atomic_write_json(out / PROVENANCE, record)
    write_model_card(out)
    return out


RUNNERS = {
    "data": stage_data, "train": stage_train, "eval-vf": stage_eval_vf, "eval": stage_eval,
    "gifs": stage_gifs, "report": stage_report, "weights": stage_weights,
}  # fmt: skip


def _check_recipes(cfg: ExperimentConfig) -> None:
    """Refuse a training recipe that cannot run now, before the data stage (not a traceback after it)."""
    for kind in MODELS:
        try:
            check_config(train_config(cfg, kind))
        except TvfError as exc:
            raise TvfError(f"{kind} training: {exc} (set by the experiment's --{kind}-* flags)") from None
    if cfg.vf_tune:
        vf_tune(cfg.preset)  # a preset without a tuning phase: the one-line error, before any work


def check_experiment(cfg: ExperimentConfig) -> ExperimentConfig:
    """The configuration with its schedules filled from the preset; a one-line error for a bad stage,
    method, recipe or backend (Ray missing, an address without it), before any work."""
    cfg = cfg.resolved()
    cfg.stage_list()
    cfg.method_list()
    _check_recipes(cfg)
    check_backend(cfg.backend, cfg.address)
    if cfg.backend == "ray":
        import_ray()
    return cfg


def run_experiment(cfg: ExperimentConfig) -> Path:
    """Run the selected stages in order; returns EXP/report.md (when the report stage ran)."""
    cfg = check_experiment(cfg)
    stages = cfg.stage_list()
    check_output_dir(cfg.out)
    _record_config(cfg)
    for stage in stages:
        _say(f"stage {stage}")
        with costed(cfg.out, stage):  # EXP/cost.jsonl: wall and CPU time, also of an interrupted stage
            RUNNERS[stage](cfg)
    if cfg.ship:
        ship_weights(cfg.out / "weights", WEIGHTS_DIR, cfg.preset)
        _say(f"shipped {cfg.out / 'weights'} to {WEIGHTS_DIR}")
    return cfg.out / "report.md"
