"""`tvf train gctn|vf`: train the learned models from a demonstration dataset."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import tyro

from tvf.cli.common import check_output_dir
from tvf.train.trainer import TrainConfig


@dataclass(frozen=True)
class TrainGctn(TrainConfig):
    """Train the goal-conditioned Transporter (pick attention + goal-conditioned place transport).

    Unset --steps/--batch/--lr/--schedule/--warmup come from the preset's recipe (lite: 14000 steps x
    batch 2, lr 2e-4 cosine with 500 warm-up steps: the shipped weights' recipe).
    Example: tvf train gctn --data data/demos --demos 10 --preset lite --out runs/gctn
    """

    def run(self) -> None:
        run_training(self, "gctn")


@dataclass(frozen=True)
class TrainVf(TrainConfig):
    """Train the visual-foresight model (next RGB-H image from the current one and an action).

    Unset recipe flags come from the preset's recipe (lite: 3000 steps x batch 8, lr 1e-4).
    Example: tvf train vf --data data/demos --demos 10 --preset lite --out runs/vf
    """

    def run(self) -> None:
        run_training(self, "vf")


def run_training(cfg: TrainConfig, kind: str) -> None:
    from tvf.runs import RunDir
    from tvf.train.registry import training_job, with_recipe  # lazy: they import the data pipeline
    from tvf.train.trainer import check_config, train

    check_config(with_recipe(cfg, kind))  # bad flags and an unwritable --out: one line, before any data
    check_output_dir(cfg.out)
    resolved, job = training_job(cfg, kind)
    val = train(resolved, job)
    shown = ", ".join(f"{k} {v:.4g}" for k, v in val.items()) or "no validation data"
    print(f"done: {RunDir(cfg.out).last} ({shown})")


@dataclass(frozen=True)
class TrainCmd:
    """Train a model: `tvf train gctn ...` or `tvf train vf ...` (resumable with --resume)."""

    command: tyro.conf.OmitArgPrefixes[
        Annotated[TrainGctn, tyro.conf.subcommand("gctn")] | Annotated[TrainVf, tyro.conf.subcommand("vf")]
    ]
    """Which model to train."""

    def run(self) -> None:
        self.command.run()
