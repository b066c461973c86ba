"""`tvf train gctn|vf`: train the learned models from a demonstration dataset."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import tyro

from tvf.train.trainer import TrainConfig


@dataclass(frozen=True)
class TrainGctn(TrainConfig):
    """Train the goal-conditioned Transporter (pick attention + goal-conditioned place transport).

    Example: tvf train gctn --data data/demos --demos 10 --preset lite --steps 2000 --out runs/gctn
    """

    def run(self) -> None:
        from tvf.train.jobs import gctn_job
        from tvf.train.trainer import train

        report(train(self, gctn_job(self)), self)


@dataclass(frozen=True)
class TrainVf(TrainConfig):
    """Train the visual-foresight model (next RGB-H image from the current one and an action).

    Example: tvf train vf --data data/demos --demos 10 --preset lite --steps 2000 --out runs/vf
    """

    def run(self) -> None:
        from tvf.train.jobs import vf_job
        from tvf.train.trainer import train

        report(train(self, vf_job(self)), self)


def report(val: dict[str, float], cfg: TrainConfig) -> None:
    shown = ", ".join(f"{k} {v:.4g}" for k, v in val.items()) or "no validation data"
    print(f"done: {cfg.out}/checkpoints/last.pt ({shown})")


@dataclass(frozen=True)
class TrainCmd:
    """Train a model: `tvf train gctn ...` or `tvf train vf ...` (resumable with --resume)."""

    command: tyro.conf.OmitArgPrefixes[
        Annotated[TrainGctn, tyro.conf.subcommand("gctn")] | Annotated[TrainVf, tyro.conf.subcommand("vf")]
    ]
    """Which model to train."""

    def run(self) -> None:
        self.command.run()
