"""The training jobs: the GCTN (pick and place), the visual-foresight (VF) model and the latent-dynamics
baseline."""

from __future__ import annotations

import math
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tvf.data.dataset import demo_subset, moves_of, open_dataset
from tvf.data.format import DataError, Episode
from tvf.data.samplers import GctnSampler, VfRolloutSampler, VfSampler
from tvf.models.checkpoint import load_initial_weights, trained_checkpoint
from tvf.models.gctn import GCTN
from tvf.models.images import from_rgbh, to_rgbh
from tvf.models.latent import LatentDynamics
from tvf.models.presets import get_preset
from tvf.models.symmetry import check_turns, symmetrized
from tvf.models.vf import VisualForesight, changed_pixel_weights
from tvf.runs import RunDir
from tvf.tasks import BLOCK_SYMMETRY, TaskTable, load_tasks
from tvf.train.pictures import gctn_pictures, vf_pictures
from tvf.train.trainer import TrainConfig, TrainError, TrainingJob, fingerprint, schedule_config
from tvf.weights import sha256_file

PICK_TOLERANCE_PX = 6
"""A predicted pick within this many pixels of the label lies on the same 4 cm block (12.8 px)."""
PLACE_TOLERANCE_PX = 3
"""A predicted place within this many pixels (~1 cm, the success tolerance) of the label is right."""


def _load_episodes(cfg: TrainConfig, kind: str) -> tuple[list[Episode], list[Episode], dict[str, Any]]:
    """The run's demo subset of the train split (and its --extra-data), the validation episodes and the
    data fingerprint."""
    tasks = [t.name for t in task_table(cfg).resolve(cfg.tasks)]
    train = open_dataset(cfg.data, split="train" if _has_splits(cfg.data) else None, tasks=tasks)
    if moves := moves_of(train.root):
        raise TrainError(
            f"{train.root} holds the own moves of {moves} (tvf demos --moves), not "
            "demonstrations: give the demonstrations as --data and this folder as --extra-data"
        )
    chosen = demo_subset(train, cfg.demos, cfg.seed, tasks)
    infos = [info for t in tasks for info in chosen[t]]
    episodes = train.load_all(infos)
    extra = _extra_episodes(cfg, kind, tasks)
    val_eps: list[Episode] = []
    val_root = cfg.val_data or (Path(cfg.data) / "test" if _has_splits(cfg.data) else None)
    if val_root is not None and Path(val_root).exists():
        try:
            val = open_dataset(val_root, split="test" if _has_splits(val_root) else None)
            val_eps = val.load_all()
        except DataError as exc:
            raise TrainError(f"validation data: {exc}") from None
    splits = {"train": episodes, "val": val_eps} | ({"extra": extra} if extra else {})
    data = {
        "data": str(cfg.data),
        "tasks": tasks,
        "demos": cfg.demos,
        "episodes": [[e.task, e.seed] for e in episodes],
        "data_fingerprint": fingerprint([[e.task, e.seed, e.n_steps] for e in episodes]),
        "data_content": data_content(splits),
    }
    if extra:
        data |= {"extra_data": str(cfg.extra_data), "extra_episodes": [[e.task, e.seed] for e in extra]}
    return episodes + extra, val_eps, data


def _extra_episodes(cfg: TrainConfig, kind: str, tasks: list[str]) -> list[Episode]:
    """Every episode of the run's tasks in ``--extra-data``, a folder of a method's own moves."""
    if cfg.extra_data is None:
        return []
    if kind == "gctn":
        raise TrainError("--extra-data adds foresight data (a method's own moves): VF and latent runs only; "
                         "the GCTN learns from the expert's demonstrations")  # fmt: skip
    try:
        extra = open_dataset(cfg.extra_data, split="train" if _has_splits(cfg.extra_data) else None)
    except DataError as exc:
        raise TrainError(f"--extra-data: {exc}") from None
    if not moves_of(extra.root):
        raise TrainError(f"--extra-data {cfg.extra_data}: holds demonstrations, not a method's own moves "
                         "(tvf demos --moves); draw more demonstrations with --demos instead")  # fmt: skip
    infos = [info for t in tasks for info in extra.episodes.get(t, [])]
    if not infos:
        names = ", ".join(tasks)
        raise TrainError(f"--extra-data {cfg.extra_data}: no episodes of the run's tasks ({names})")
    return extra.load_all(infos)


def data_content(splits: dict[str, list[Episode]]) -> dict[str, Any]:
    """The content a run trains and validates on: each episode file's content digest (the SHA-256 of its
    checksums, which every read checks the arrays against) by ``SPLIT:TASK/SEED``, and one digest of them
    all. A resume compares it with the run's record (:meth:`tvf.runs.RunDir.prepare`)."""
    files = {f"{split}:{e.task}/{e.seed}": _content(e) for split, eps in splits.items() for e in eps}
    return {"digest": fingerprint(sorted(files.items())), "episodes": files}


def _content(episode: Episode) -> str:
    if episode.path is None:
        return "in memory"
    return (episode.checksum or "unverified")[:16]  # format 1 files carry no checksums


def task_table(cfg: TrainConfig) -> TaskTable:
    """The tasks a run may name: the built-in ones plus its --task-file's."""
    return load_tasks(cfg.task_file)


def _has_splits(path: Path | str) -> bool:
    return (Path(path) / "train").is_dir() or (Path(path) / "test").is_dir()


def _fixed_items(sampler, n: int) -> list[dict[str, torch.Tensor]]:
    """``n`` un-augmented samples spread evenly over the sampler's (episode, step) pairs."""
    idx = np.unique(np.linspace(0, len(sampler) - 1, num=min(n, len(sampler))).round().astype(int))
    return [sampler.item(int(i)) for i in idx]


def _stack(items: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    return {k: torch.cat([it[k] for it in items]) for k in items[0]}


def _base_config(kind: str, cfg: TrainConfig, model, data: dict[str, Any]) -> dict[str, Any]:
    return {"kind": kind, "preset": model.preset.as_dict(), "seed": cfg.seed, "batch": cfg.batch,
            "lr": cfg.lr, "schedule": schedule_config(cfg), **data}  # fmt: skip


def _job(
    kind: str, cfg: TrainConfig, model, sampler_cls, loss, metrics, pictures, judged=None, train_sampler=None,
    **val_kwargs,
) -> TrainingJob:  # fmt: skip
    """A job from a model, its sampler class, a batch loss, a validation metric function and the pictures
    of one validation sample (the middle one of the fixed samples); ``judged`` is the module validated
    and drawn (default ``model``, the one trained and saved); ``train_sampler`` the class that draws the
    training batches when it is not ``sampler_cls`` (which always draws the validation samples)."""
    judged = model if judged is None else judged
    init = _init_source(cfg, kind)  # before the data: a bad --init fails at once
    episodes, val_eps, data = _load_episodes(cfg, kind)
    r = model.preset.n_rotations  # the samplers' rotation bins are the model's
    sampler = (train_sampler or sampler_cls)(
        episodes, batch_size=cfg.batch, augment=True, seed=cfg.seed, n_rotations=r
    )
    validate = draw = None
    if val_eps:
        val_sampler = sampler_cls(val_eps, augment=False, n_rotations=r, **val_kwargs)
        val_items = _fixed_items(val_sampler, cfg.val_samples)

        def validate() -> dict[str, float]:
            return metrics(judged, val_items, next(model.parameters()).device)

        def draw() -> dict[str, np.ndarray]:
            return pictures(judged, val_items[len(val_items) // 2], next(model.parameters()).device)

    job = TrainingJob(kind, model, partial(sampler.sample, cfg.batch), loss, validate,
                      _base_config(kind, cfg, model, data), draw)  # fmt: skip
    if init is not None:
        job.config["init"] = _initialise(model, init, kind)
    elif cfg.init is not None:  # resumed: its own checkpoint holds the weights; keep the record it began with
        job.config["init"] = RunDir(cfg.out).read_config().get("init")
    return job


def _init_source(cfg: TrainConfig, kind: str) -> Path | None:
    """The checkpoint ``--init`` names (a run folder: its last checkpoint), or None without ``--init`` and
    when the run is resumed from a checkpoint of its own (which then replaces the weights anyway)."""
    if cfg.init is None or (cfg.resume and RunDir(cfg.out).last.exists()):
        return None
    return trained_checkpoint(cfg.init, kind)


INIT_FREE_FIELDS = ("vf_head",)
"""Preset fields a run may change from its --init weights: the VF's head reads the same network's output
another way (a fine-tune may switch it; the weights must still fit)."""


def _initialise(model, path: Path, kind: str) -> dict[str, Any]:
    """Load the weights of ``path`` (of ``kind`` and the model's preset, up to :data:`INIT_FREE_FIELDS`)
    into ``model``; what the run's config records of them: the step and the file's SHA-256."""
    ckpt = load_initial_weights(model, path, kind, free=INIT_FREE_FIELDS)
    return {"step": ckpt.step, "sha256": sha256_file(path)}


def _refuse_turns(cfg: TrainConfig, model: str) -> None:
    if cfg.turns not in (None, 1):
        raise TrainError(f"--turns is a GCTN flag (its maps averaged over quarter turns); the {model} has no "
                         "such maps: leave it out")  # fmt: skip


def _refuse_gctn_network_flags(cfg: TrainConfig, model: str) -> None:
    if cfg.gctn_kernels is not None:
        raise TrainError(f"--gctn-kernels is a GCTN flag (its FCNs' kernels); the {model} has none of "
                         "those: leave it out")  # fmt: skip
    if cfg.gctn_width is not None:
        raise TrainError(f"--gctn-width is a GCTN flag (its FCNs' width); the {model} takes its width from "
                         "the preset: leave it out")  # fmt: skip


def _refuse_gctn_sample_flags(cfg: TrainConfig, model: str) -> None:
    if cfg.hindsight:
        raise TrainError(f"--hindsight is a GCTN flag (the goals of its samples); the {model} has no goal "
                         "image: leave it out")  # fmt: skip
    if cfg.mirror:
        raise TrainError(f"--mirror is a GCTN flag (mirror images of its samples); the {model} is trained "
                         "without them: leave it out")  # fmt: skip


def _refuse_rollout(cfg: TrainConfig, model: str) -> None:
    if (cfg.vf_rollout or 1) > 1:
        raise TrainError(f"--vf-rollout is a VF flag (its multi-step loss); the {model} is trained on single "
                         "steps: leave it out")  # fmt: skip


def check_gctn_width(width: float) -> float:
    """``width`` if it is a usable width multiplier of the GCTN's FCNs; otherwise a one-line error."""
    if not (0.03 <= width <= 2.0):
        raise TrainError(f"--gctn-width must be between 0.03 and 2 (a multiple of the paper's channels: lite "
                         f"0.125, paper 1), got {width}; fix --gctn-width")  # fmt: skip
    return width


def gctn_job(cfg: TrainConfig, sampler_cls: type = GctnSampler) -> TrainingJob:
    """Training job for the goal-conditioned Transporter (with ``turns`` > 1: its symmetrised maps, which
    are also what is validated; the plain GCTN inside is what is saved)."""
    _refuse_rollout(cfg, "GCTN")
    preset = get_preset(cfg.preset)
    if cfg.gctn_kernels is not None:
        preset = preset.replace(gctn_kernels=cfg.gctn_kernels)
    if cfg.gctn_width is not None:
        width = check_gctn_width(cfg.gctn_width)
        preset = preset.replace(attention_width=width, transport_width=width)
    model = GCTN(preset, seed=cfg.seed)
    turns = check_turns(1 if cfg.turns is None else cfg.turns)
    trained = symmetrized(model, turns)

    def loss(batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, float]]:
        current = to_rgbh(batch["current_color"], batch["current_height"])
        goal = to_rgbh(batch["goal_color"], batch["goal_height"])
        losses = trained.loss(current, goal, batch["pick"], batch["place"], batch["rot_bin"])
        return losses["total"], {k if k != "total" else "loss": float(v.detach()) for k, v in losses.items()}

    drawing = {k: v for k, v in (("hindsight", cfg.hindsight), ("mirror", cfg.mirror)) if v}
    drawn = partial(sampler_cls, **drawing) if drawing else None
    job = _job("gctn", cfg, model, sampler_cls, loss, gctn_metrics, gctn_pictures, judged=trained,
               train_sampler=drawn)  # fmt: skip
    if turns > 1:  # part of what a resumed run must match; absent: the plain GCTN's loss
        job.config["turns"] = turns
    job.config.update(drawing)  # likewise; absent: every goal the last frame, no sample mirrored
    return job


@torch.no_grad()
def gctn_metrics(model, items: list[dict[str, torch.Tensor]], device: torch.device) -> dict[str, float]:
    """Loss and greedy accuracies on fixed samples: pick on the labelled block, place within ~1 cm
    with the rotation within one bin modulo the block's symmetry (a quarter turn)."""
    out: dict[str, list[float]] = {"loss": [], "pick_acc": [], "place_acc": []}
    r = model.preset.n_rotations
    for chunk in range(0, len(items), 8):
        b = {k: v.to(device) for k, v in _stack(items[chunk : chunk + 8]).items()}
        current = to_rgbh(b["current_color"], b["current_height"])
        goal = to_rgbh(b["goal_color"], b["goal_height"])
        out["loss"].append(float(model.loss(current, goal, b["pick"], b["place"], b["rot_bin"])["total"]))
        pick, place, rot, _ = model.act(current, goal)
        # the place is judged at the labelled pick, so the two accuracies are separate
        place_logits = model.place_map(current, goal, b["pick"])
        flat = place_logits.flatten(1).argmax(1)
        h, w = place_logits.shape[-2:]
        place_at_label = torch.stack([(flat % (h * w)) // w, flat % w], 1)
        rot_at_label = flat // (h * w)
        out["pick_acc"] += ((pick - b["pick"]).abs().max(1).values <= PICK_TOLERANCE_PX).float().tolist()
        period = round(r * BLOCK_SYMMETRY / (2 * math.pi))  # bins per symmetry period of a block
        drot = (rot_at_label - b["rot_bin"]) % period
        rot_ok = torch.minimum(drot, period - drot) <= 1
        close = (place_at_label - b["place"]).abs().max(1).values <= PLACE_TOLERANCE_PX
        out["place_acc"] += (close & rot_ok).float().tolist()
    return {k: float(np.mean(v)) for k, v in out.items()}


def vf_job(cfg: TrainConfig, sampler_cls: type = VfSampler) -> TrainingJob:
    """Training job for the visual-foresight model (validated on oracle steps, no identity samples)."""
    _refuse_turns(cfg, "visual-foresight model")
    _refuse_gctn_network_flags(cfg, "visual-foresight model")
    _refuse_gctn_sample_flags(cfg, "visual-foresight model")
    preset = get_preset(cfg.preset)
    if cfg.vf_head is not None:
        preset = preset.replace(vf_head=cfg.vf_head)
    model = VisualForesight(preset, seed=cfg.seed)
    horizon = cfg.vf_rollout or 1

    def loss(batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, float]]:
        current = to_rgbh(batch["current_color"], batch["current_height"])
        target = to_rgbh(batch["next_color"], batch["next_height"])
        weights = None
        if cfg.vf_changed_weight:
            extra = cfg.vf_changed_weight
            weights = changed_pixel_weights(batch["current_height"], batch["next_height"], extra)
        value = model.loss(current, batch["pick"], batch["place"], batch["yaw"], target, weights)
        return value, {"loss": float(value.detach())}

    def rollout_loss(batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, float]]:
        heights = [batch["current_height"], *(batch[f"frame{k}_height"] for k in range(1, horizon + 1))]
        targets = [to_rgbh(batch[f"frame{k}_color"], heights[k]) for k in range(1, horizon + 1)]
        weights = None
        if cfg.vf_changed_weight:
            pairs = zip(heights, heights[1:], strict=False)  # each step's before and after
            weights = [changed_pixel_weights(a, b, cfg.vf_changed_weight) for a, b in pairs]
        current = to_rgbh(batch["current_color"], batch["current_height"])
        value = model.rollout_loss(current, batch["picks"], batch["places"], batch["yaws"], targets, weights)
        return value, {"loss": float(value.detach())}

    rollouts = partial(VfRolloutSampler, horizon=horizon) if horizon > 1 else None
    job = _job("vf", cfg, model, sampler_cls, rollout_loss if rollouts else loss, vf_metrics, vf_pictures,
               train_sampler=rollouts, identity_fraction=0.0)  # fmt: skip
    # part of what a resumed run must match; absent: the reference's loss
    recorded = {"changed_weight": cfg.vf_changed_weight, "rollout": horizon if horizon > 1 else None}
    if any(recorded.values()):
        job.config["loss"] = {k: v for k, v in recorded.items() if v}
    return job


def _prediction_errors(model, b: dict[str, torch.Tensor], current: torch.Tensor) -> tuple[float, float]:
    """Colour MAE in [0, 1] and height MAE in mm of the clamped prediction of one validation chunk."""
    color, height = from_rgbh(model.predict_rgbh(current, b["pick"], b["place"], b["yaw"]))
    return (float((color - b["next_color"]).abs().mean() / 255.0),
            float((height - b["next_height"]).abs().mean() * 1000.0))  # fmt: skip


@torch.no_grad()
def vf_metrics(model, items: list[dict[str, torch.Tensor]], device: torch.device) -> dict[str, float]:
    """Validation loss and physical errors: colour MAE in [0, 1] and height MAE in mm."""

    losses, color_err, height_err = [], [], []
    for chunk in range(0, len(items), 8):
        b = {k: v.to(device) for k, v in _stack(items[chunk : chunk + 8]).items()}
        current = to_rgbh(b["current_color"], b["current_height"])
        target = to_rgbh(b["next_color"], b["next_height"])
        losses.append(float(model.loss(current, b["pick"], b["place"], b["yaw"], target)))
        color, height = _prediction_errors(model, b, current)
        color_err.append(color)
        height_err.append(height)
    return {"loss": float(np.mean(losses)), "color_mae": float(np.mean(color_err)),
            "height_mae_mm": float(np.mean(height_err))}  # fmt: skip


def latent_job(cfg: TrainConfig, sampler_cls: type = VfSampler) -> TrainingJob:
    """Training job for the latent-dynamics baseline: the VF's data, sampler, augmentation and validation;
    ``--vf-changed-weight`` weighs its next-image loss as the VF's."""
    if cfg.vf_head is not None:
        raise TrainError("--vf-head is a VF flag; the latent-dynamics model has no output head to choose")
    _refuse_turns(cfg, "latent-dynamics model")
    _refuse_gctn_network_flags(cfg, "latent-dynamics model")
    _refuse_gctn_sample_flags(cfg, "latent-dynamics model")
    _refuse_rollout(cfg, "latent-dynamics model")
    model = LatentDynamics(get_preset(cfg.preset), seed=cfg.seed)

    def loss(batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, float]]:
        current = to_rgbh(batch["current_color"], batch["current_height"])
        target = to_rgbh(batch["next_color"], batch["next_height"])
        weights, extra = None, cfg.vf_changed_weight
        if extra:
            weights = changed_pixel_weights(batch["current_height"], batch["next_height"], extra)
        parts = model.losses(current, batch["pick"], batch["place"], batch["yaw"], target, weights)
        return parts["total"], {k if k != "total" else "loss": float(v.detach()) for k, v in parts.items()}

    job = _job("latent", cfg, model, sampler_cls, loss, latent_metrics, vf_pictures, identity_fraction=0.0)
    job.config["latent"] = model.latent.as_dict()
    # the loss weights: what a resumed run must match
    job.config["loss"] = {k: v for k, v in model.latent.as_dict().items() if k.endswith("_weight")}
    if cfg.vf_changed_weight:
        job.config["loss"]["changed_weight"] = cfg.vf_changed_weight
    return job


@torch.no_grad()
def latent_metrics(model, items: list[dict[str, torch.Tensor]], device: torch.device) -> dict[str, float]:
    """Validation loss (``loss``, as the VF's: the next image's L1), the other loss terms and the VF's
    physical errors."""
    out: dict[str, list[float]] = {k: [] for k in ("loss", "recon", "latent", "color_mae", "height_mae_mm")}
    for chunk in range(0, len(items), 8):
        b = {k: v.to(device) for k, v in _stack(items[chunk : chunk + 8]).items()}
        current = to_rgbh(b["current_color"], b["current_height"])
        target = to_rgbh(b["next_color"], b["next_height"])
        parts = model.losses(current, b["pick"], b["place"], b["yaw"], target)
        out["loss"].append(float(parts["next"]))
        out["recon"].append(float(parts["recon"]))
        out["latent"].append(float(parts["latent"]))
        color, height = _prediction_errors(model, b, current)
        out["color_mae"].append(color)
        out["height_mae_mm"].append(height)
    return {k: float(np.mean(v)) for k, v in out.items()}
