"""Where a training run's numbers and pictures go besides metrics.jsonl: TensorBoard (RUN/tb/) always,
Weights & Biases with ``--wandb`` (an optional extra, imported only then; its files go to RUN/wandb/).

Both get the same scalars as metrics.jsonl (``train/KEY``, ``val/KEY`` at the optimiser step) and the
validation pictures (``images/NAME``, :mod:`tvf.train.pictures`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from torch.utils.tensorboard import SummaryWriter  # heavy, but every use of this module trains

from tvf.errors import TvfError

WANDB_PROJECT = "tvf"
"""The W&B project of runs when WANDB_PROJECT is not set."""


def import_wandb() -> ModuleType:
    """The wandb package, or a one-line error saying how to install it."""
    try:
        import wandb  # optional extra: imported only for --wandb
    except ImportError:
        raise TvfError(
            "--wandb needs the wandb package: pip install 'tvf[wandb]' (or pip install wandb)"
        ) from None
    return wandb


class Sinks:
    """The run's TensorBoard writer and, optionally, its W&B run."""

    def __init__(self, tb: Path, purge_step: int | None, wandb_run: Any = None) -> None:
        self.writer = SummaryWriter(str(tb), purge_step=purge_step)
        self.wandb_run = wandb_run

    def scalars(self, split: str, values: dict[str, float], step: int) -> None:
        for k, v in values.items():
            self.writer.add_scalar(f"{split}/{k}", v, step)
        if self.wandb_run is not None:
            self.wandb_run.log({f"{split}/{k}": v for k, v in values.items()}, step=step)

    def images(self, images: dict[str, np.ndarray], step: int) -> None:
        """uint8 (H, W, 3) pictures under ``images/NAME``."""
        for name, image in images.items():
            self.writer.add_image(f"images/{name}", image, step, dataformats="HWC")
        if self.wandb_run is not None:
            wandb = import_wandb()
            self.wandb_run.log({f"images/{n}": wandb.Image(im) for n, im in images.items()}, step=step)

    def close(self) -> None:
        self.writer.close()
        if self.wandb_run is not None:
            self.wandb_run.finish()
            self.wandb_run = None


def start_wandb(root: Path, config: dict[str, Any]) -> Any:
    """A W&B run named after the run folder, with the run's config, writing under ROOT/wandb/.

    WANDB_PROJECT, WANDB_ENTITY and WANDB_MODE (e.g. ``offline``) are honoured as W&B documents them.
    """
    wandb = import_wandb()
    (root / "wandb").mkdir(parents=True, exist_ok=True)
    try:
        return wandb.init(
            project=os.environ.get("WANDB_PROJECT", WANDB_PROJECT),
            name=root.resolve().name,
            dir=str(root),
            config=json.loads(json.dumps(config, default=str)),
        )
    except Exception as exc:  # wandb raises its own error types (no login, no network)
        msg = " ".join(str(exc).split())
        raise TvfError(f"W&B did not start ({msg}); run `wandb login` or set WANDB_MODE=offline") from None
