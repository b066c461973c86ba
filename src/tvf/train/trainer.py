"""One training loop for both learned models, with a run directory that can be resumed.

The run directory's layout is :mod:`tvf.runs`'s (config.json, metrics.jsonl, tb/, checkpoints/).

Every batch draws its randomness from ``numpy.random.default_rng([seed, step])``, so a resumed run
sees exactly the batches an uninterrupted run would have seen, whether the training thread or
DataLoader workers (``--loader-workers``) build them. Under torchrun (:mod:`tvf.train.distributed`)
every process builds its slice of that same global batch, gradients are averaged, and rank 0 alone
writes the run folder. A full disk stops the run with one :class:`~tvf.errors.DiskFullError` naming the
checkpoint that ``--resume`` continues from.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset
from tqdm import tqdm

from tvf import __version__
from tvf.device import pick_device
from tvf.errors import RERUN, TvfError
from tvf.io import as_disk_full, atomic_path
from tvf.models.checkpoint import load_checkpoint, save_checkpoint
from tvf.runs import RunDir
from tvf.train.config import TrainConfig
from tvf.train.distributed import (
    World,
    average_gradients,
    broadcast_module,
    check_batch,
    decided_by_main,
    from_main,
    joined,
    mean_numbers,
    world_from_env,
)
from tvf.train.sinks import Sinks, import_wandb, start_wandb


class TrainError(TvfError):
    """A training run that cannot start or resume (bad data, mismatched run directory)."""


SCHEDULES = ("constant", "cosine")
RESUME_MATCH = (
    "kind", "preset", "data_fingerprint", "seed", "batch", "lr", "schedule", "loss", "turns", "hindsight",
    "mirror", "init",
)  # fmt: skip
"""What a resumed run must share with the run it continues."""


def learning_rate(cfg: TrainConfig, step: int) -> float:
    """The learning rate of optimiser step ``step`` (1-based): a pure function, so resumes are exact."""
    if cfg.schedule == "constant":
        return cfg.lr
    if step <= cfg.warmup:
        return cfg.lr * step / cfg.warmup
    progress = (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup)
    return cfg.lr * 0.5 * (1.0 + math.cos(math.pi * min(1.0, progress)))


def schedule_config(cfg: TrainConfig) -> dict[str, Any]:
    """What fixes the schedule; a resumed run must match it (a cosine run's length is part of it)."""
    if cfg.schedule == "constant":
        return {"name": "constant"}
    return {"name": cfg.schedule, "warmup": cfg.warmup, "steps": cfg.steps}


def fingerprint(items: list[Any]) -> str:
    """A short stable hash of JSON-able items (the data a run was trained on)."""
    return hashlib.sha1(json.dumps(items, sort_keys=True, default=str).encode()).hexdigest()[:16]


@dataclass
class TrainingJob:
    """What differs between the models: how to build them, a loss per batch and validation."""

    kind: str
    model: torch.nn.Module
    train_batch: Callable[[np.random.Generator, slice | None], dict[str, torch.Tensor]]
    """``train_batch(rng, part)``: draw one augmented batch from ``rng`` and build the samples ``part`` of
    it (None: all; tensors on the CPU). Picklable, for DataLoader workers."""
    loss: Callable[[dict[str, torch.Tensor]], tuple[torch.Tensor, dict[str, float]]]
    validate: Callable[[], dict[str, float]] | None
    config: dict[str, Any]
    pictures: Callable[[], dict[str, np.ndarray]] | None = None
    """Pictures of a fixed validation sample (name -> uint8 (H, W, 3)), logged with the validation."""


def wants_pictures(cfg: TrainConfig, step: int) -> bool:
    """Whether the validation at ``step`` logs pictures: every ``images_every``-th one and the last."""
    if cfg.images_every <= 0:
        return False
    return step == cfg.steps or (step // cfg.val_every) % cfg.images_every == 0


def _to(batch: dict[str, torch.Tensor], device: torch.device) -> dict[str, torch.Tensor]:
    return {k: v.to(device, non_blocking=True) if torch.is_tensor(v) else v for k, v in batch.items()}


COUNT_FLAGS = ("steps", "batch", "demos", "val_every", "val_samples", "checkpoint_every", "log_every")
"""Flags that count something and must be at least 1."""


def check_config(cfg: TrainConfig) -> None:
    """Refuse a resolved configuration that cannot train, with one line naming the flag (before any work)."""
    if None in (cfg.steps, cfg.batch, cfg.lr, cfg.schedule, cfg.warmup):
        raise TrainError("the training recipe is incomplete; resolve it with tvf.train.registry.with_recipe")
    low = [f"--{name.replace('_', '-')}" for name in COUNT_FLAGS if getattr(cfg, name) < 1]
    if low:
        raise TrainError(f"{', '.join(low)} must be at least 1")
    if not (math.isfinite(cfg.lr) and cfg.lr > 0):
        raise TrainError(f"--lr must be a positive number, not {cfg.lr}")
    if cfg.schedule not in SCHEDULES:
        raise TrainError(f"unknown --schedule {cfg.schedule!r}; choose {' or '.join(SCHEDULES)}")
    if not 0 <= cfg.warmup < cfg.steps:
        raise TrainError(f"--warmup must be at least 0 and below --steps ({cfg.steps}), not {cfg.warmup}")
    weight = cfg.vf_changed_weight
    if weight is not None and not (math.isfinite(weight) and weight >= 0):
        raise TrainError(f"--vf-changed-weight must be 0 (the reference's loss) or more, not {weight}")
    if cfg.vf_rollout is not None and cfg.vf_rollout < 1:
        rollout = cfg.vf_rollout
        raise TrainError(f"--vf-rollout must be 1 (the reference's one-step loss) or more, not {rollout}")
    for flag in ("hindsight", "mirror"):
        share = getattr(cfg, flag)
        if not 0.0 <= share <= 1.0:  # NaN too
            raise TrainError(f"--{flag} {share}: a share of the samples, between 0 and 1 (0: the paper's)")
    for name in ("threads", "loader_workers", "keep"):
        if getattr(cfg, name) < 0:
            flag = f"--{name.replace('_', '-')}"
            raise TrainError(f"{flag} must be 0 (the default) or more, not {getattr(cfg, name)}")
    if cfg.restart and not cfg.resume:
        raise TrainError("--restart goes with --resume (it restarts a resumed run whose data changed)")
    check_batch(cfg.batch, world_from_env())
    if cfg.images_every < 0:
        raise TrainError(f"--images-every must be 0 (no images) or more, not {cfg.images_every}")
    if cfg.wandb:
        import_wandb()  # a missing package fails before the run folder is made


_LOSS = "\0loss"
"""The key under which the step's loss joins its metrics for the average over the processes."""

RESUME_HINT = "re-run the same command with --resume to continue"


def train(cfg: TrainConfig, job: TrainingJob) -> dict[str, float]:
    """Run (or resume) training; returns the last validation metrics. A full disk is a
    :class:`~tvf.errors.DiskFullError` saying which checkpoint is kept (a partial one is removed)."""
    check_config(cfg)
    saved: list[int] = []  # the steps checkpointed into RUN/checkpoints/last.pt, by this call or before
    try:
        return _train(cfg, job, saved)
    except Exception as exc:
        full = as_disk_full(exc, cfg.out)
        if full is None:
            raise
        rerun = RERUN if cfg.resume else RESUME_HINT  # a run started with --resume resumes as it is
        raise full.keeping(_kept(RunDir(cfg.out), saved), rerun) from exc


def _kept(run: RunDir, saved: list[int]) -> str:
    if saved:
        return f"checkpoint step {saved[-1]} kept in {run.last}"
    return "no checkpoint written yet"


def _train(cfg: TrainConfig, job: TrainingJob, saved: list[int]) -> dict[str, float]:
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    world = world_from_env()
    with joined(world, pick_device(cfg.device)) as device:
        val = _train_on(cfg, job, saved, world, device)
        return from_main(world, val)  # every process returns rank 0's validation


def _train_on(
    cfg: TrainConfig, job: TrainingJob, saved: list[int], world: World, device: torch.device
) -> dict[str, float]:
    run = RunDir(cfg.out)
    config = {**job.config, "train": asdict(cfg), "version": __version__, "device": device.type}
    if world.several:
        config["processes"] = world.size
    decided_by_main(world, lambda: run.prepare(config, cfg.resume, RESUME_MATCH, cfg.restart))
    model = job.model.to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    start, val = 0, {}  # val: the last validation metrics (a resumed run starts from its checkpoint's)
    if cfg.resume and run.last.exists():  # every process resumes from the same checkpoint
        ckpt = load_checkpoint(run.last, job.kind, expected_config=model.config())
        model.load_state_dict(ckpt.model)
        if ckpt.optimizer is not None:
            optimizer.load_state_dict(interned(ckpt.optimizer))
        start = ckpt.step
        val = interned(dict((ckpt.extra or {}).get("val") or {}))  # the validation the checkpoint recorded
        saved.append(start)
    broadcast_module(world, model)  # the processes start from rank 0's weights
    if cfg.resume and world.main:  # records logged after the checkpoint (or, without one, at all) are
        # logged again
        run.truncate_metrics(start)
    if start >= cfg.steps:
        if world.main:
            print(f"{run.root}: already trained for {start} steps (--steps {cfg.steps}); nothing to do")
        return {}
    sinks = None
    if world.main:
        wandb_run = start_wandb(run.root, config) if cfg.wandb else None
        sinks = Sinks(run.tb, start if start else None, wandb_run)
    failed = True
    try:
        val = _loop(cfg, job, run, optimizer, sinks, world, device, start, val, saved)
        failed = False
    finally:
        if sinks is not None:
            _close(sinks, quietly=failed)
    return val


def _loop(
    cfg: TrainConfig, job: TrainingJob, run: RunDir, optimizer: torch.optim.Optimizer, sinks: Sinks | None,
    world: World, device: torch.device, start: int, val: dict[str, float], saved: list[int],
) -> dict[str, float]:  # fmt: skip
    """Steps ``start + 1 .. cfg.steps``; rank 0 logs, validates and checkpoints. Returns the last
    validation."""
    model = job.model
    amp = device.type == "cuda"
    show = cfg.progress and world.main
    bar = tqdm(total=cfg.steps, initial=start, desc=f"train {job.kind}", unit="step", disable=not show)
    window: list[dict[str, float]] = []
    t_last = time.perf_counter()
    batches = step_batches(cfg, job, start, world.share(cfg.batch), pin=amp)
    try:
        for step, batch in zip(range(start + 1, cfg.steps + 1), batches, strict=False):
            model.train()
            batch = _to(batch, device)
            lr = learning_rate(cfg, step)
            for group in optimizer.param_groups:
                group["lr"] = lr
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=amp):
                loss, metrics = job.loss(batch)
            # the global batch's numbers (one process: its own), so every process sees the same loss
            metrics = mean_numbers(world, {**metrics, _LOSS: loss.item()}, device)
            value = metrics.pop(_LOSS)
            if not math.isfinite(value):
                raise TrainError(f"the loss became {value} at step {step}; lower --lr or check the data")
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            average_gradients(world, model.parameters())
            optimizer.step()
            if not world.main:
                continue
            window.append(metrics)
            bar.update()
            if step % cfg.log_every == 0 or step == cfg.steps:
                now = time.perf_counter()
                means = {k: float(np.mean([m[k] for m in window])) for k in window[0]}
                means["steps_per_s"] = len(window) / max(now - t_last, 1e-9)
                means["lr"] = lr
                t_last, window = now, []
                run.log({"step": step, "split": "train", **means})
                sinks.scalars("train", means, step)
                bar.set_postfix(loss=f"{means['loss']:.4f}")
            if job.validate is not None and (step % cfg.val_every == 0 or step == cfg.steps):
                model.eval()
                val = job.validate()
                run.log({"step": step, "split": "val", **val})
                sinks.scalars("val", val, step)
                if job.pictures is not None and wants_pictures(cfg, step):
                    sinks.images(job.pictures(), step)
                t_last = time.perf_counter()  # steps_per_s counts training only
            if step % cfg.checkpoint_every == 0 or step == cfg.steps:
                _checkpoint(run, model, optimizer, step, job, val)
                saved.append(step)
                prune_checkpoints(run, cfg.keep)  # only now that the new one is safely written
    finally:
        bar.close()
    return val


def _checkpoint(
    run: RunDir, model: torch.nn.Module, optimizer: torch.optim.Optimizer, step: int, job: TrainingJob,
    val: dict[str, float],
) -> None:  # fmt: skip
    """Write step ``step``'s checkpoint and then last.pt, each atomically."""
    path = save_checkpoint(
        run.step_checkpoint(step), model, optimizer, step, model.config(),
        {"data_fingerprint": job.config.get("data_fingerprint"), "val": val},
    )  # fmt: skip
    with atomic_path(run.last) as tmp:
        shutil.copyfile(path, tmp)


def prune_checkpoints(run: RunDir, keep: int) -> list[Path]:
    """Delete all but the newest ``keep`` step checkpoints (0: keep all); last.pt is never touched.
    Returns the deleted files."""
    if keep <= 0:
        return []
    old = [path for _, path in run.step_checkpoints()[:-keep]]
    for path in old:
        path.unlink(missing_ok=True)
    return old


class StepBatches(Dataset):
    """The batch of each step ``steps[i]`` (its randomness keyed on (seed, step)), for DataLoader workers."""

    def __init__(self, draw: Callable, seed: int, steps: range, part: slice | None) -> None:
        self.draw, self.seed, self.steps, self.part = draw, seed, steps, part

    def __len__(self) -> int:
        return len(self.steps)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return self.draw(np.random.default_rng([self.seed, self.steps[i]]), self.part)


def step_batches(
    cfg: TrainConfig, job: TrainingJob, start: int, part: slice | None, pin: bool = False
) -> Iterator[dict[str, torch.Tensor]]:
    """The batches of steps ``start + 1 .. cfg.steps`` in order (this process's ``part`` of each): built
    in this thread, or ahead of time by ``cfg.loader_workers`` DataLoader workers (the same batches)."""
    steps = range(start + 1, cfg.steps + 1)
    if cfg.loader_workers == 0:
        return (job.train_batch(np.random.default_rng([cfg.seed, step]), part) for step in steps)
    batches = StepBatches(job.train_batch, cfg.seed, steps, part)
    loader = DataLoader(
        batches, batch_size=None, shuffle=False, num_workers=cfg.loader_workers, pin_memory=pin
    )
    return iter(loader)


def interned(value: Any) -> Any:
    """``value`` with every string in it interned, as the optimiser's own keys are: the next checkpoint
    then pickles to the same bytes as an uninterrupted run's (pickle shares one object seen twice)."""
    if isinstance(value, str):
        return sys.intern(value)
    if isinstance(value, dict):
        return {interned(k): interned(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(interned(v) for v in value)
    return value


def _close(sinks: Sinks, quietly: bool) -> None:
    """Close the sinks; ``quietly`` (an error is already on its way) drops a second error, e.g. TensorBoard
    failing to flush onto the same full disk."""
    try:
        sinks.close()
    except Exception:
        if not quietly:
            raise
