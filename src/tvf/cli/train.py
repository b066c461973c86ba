"""`tvf train gctn|vf|latent`: train the learned models from a demonstration dataset.

`tvf train [KIND] --config RUN/config.json [FLAG ...]` relaunches a saved run: the resolved flags saved in
its config.json become the defaults and the flags given beside --config override them.
"""

from __future__ import annotations

import typing
from dataclasses import MISSING, dataclass, fields
from pathlib import Path
from typing import Annotated, Any

import tyro

from tvf.cli.common import output_dir
from tvf.errors import TvfError
from tvf.io import read_json
from tvf.train.config import TrainConfig


@dataclass(frozen=True)
class _TrainFlags(TrainConfig):
    config: Path | None = None
    """Relaunch the run saved in this RUN/config.json: its resolved flags become the defaults and flags
    given beside --config override them (`tvf train --config RUN/config.json --out NEW`; into RUN
    itself with --resume)."""


@dataclass(frozen=True)
class TrainGctn(_TrainFlags):
    """Train the goal-conditioned Transporter (pick attention + goal-conditioned place transport).

    Unset --steps/--batch/--lr/--schedule/--warmup come from the preset's recipe (lite: 21000 steps x
    batch 2, lr 2e-4 cosine with 500 warm-up steps: the shipped weights' recipe).
    Example: tvf train gctn --data data/demos --demos 10 --preset lite --out runs/gctn
    """

    def run(self) -> None:
        run_training(self, "gctn")


@dataclass(frozen=True)
class TrainVf(_TrainFlags):
    """Train the visual-foresight model (next RGB-H image from the current one and an action).

    Unset recipe flags come from the preset's recipe (lite: 3000 steps x batch 8, lr 1e-4).
    Example: tvf train vf --data data/demos --demos 10 --preset lite --out runs/vf
    """

    def run(self) -> None:
        run_training(self, "vf")


@dataclass(frozen=True)
class TrainLatent(_TrainFlags):
    """Train the latent-dynamics baseline (encoder -> action-conditioned latent step -> decoder) for the
    foresight table, with the VF's data, sampler and schedule; evaluate it with `tvf eval-vf --latent RUN`.

    Unset recipe flags come from the preset's recipe, the VF's (lite: 3000 steps x batch 8, lr 1e-4);
    --vf-changed-weight weighs its next-image loss as the VF's. docs/models.md, "Latent-dynamics baseline".
    Example: tvf train latent --data data/demos --demos 10 --preset lite --out runs/latent
    """

    def run(self) -> None:
        run_training(self, "latent")


KINDS: dict[str, type[_TrainFlags]] = {"gctn": TrainGctn, "vf": TrainVf, "latent": TrainLatent}
"""The `tvf train` subcommand of each model kind (tvf.train.registry.KINDS has the same names)."""


def run_training(cfg: TrainConfig, kind: str) -> None:
    from tvf.runs import RunDir
    from tvf.train.distributed import world_from_env
    from tvf.train.registry import training_job, with_recipe  # lazy: they import the data pipeline
    from tvf.train.trainer import check_config, train

    check_config(with_recipe(cfg, kind))  # bad flags and an unwritable --out: one line, before any data
    with output_dir(cfg.out):  # a bad --init or data: no empty --out folder left behind
        resolved, job = training_job(cfg, kind)
    val = train(resolved, job)
    if world_from_env().main:  # under torchrun, rank 0 speaks for the run
        shown = ", ".join(f"{k} {v:.4g}" for k, v in val.items()) or "no validation data"
        print(f"done: {RunDir(cfg.out).last} ({shown})")


@dataclass(frozen=True)
class TrainCmd:
    """Train a model: `tvf train gctn ...`, `tvf train vf ...` or `tvf train latent ...` (resumable with
    --resume).

    `tvf train --config RUN/config.json --out NEW` relaunches a saved run exactly (the same flags, data
    and seed: the same weights); flags given beside --config override the saved ones.
    """

    command: tyro.conf.OmitArgPrefixes[
        Annotated[TrainGctn, tyro.conf.subcommand("gctn")]
        | Annotated[TrainVf, tyro.conf.subcommand("vf")]
        | Annotated[TrainLatent, tyro.conf.subcommand("latent")]
    ]
    """Which model to train."""

    def run(self) -> None:
        self.command.run()


def split_config_flag(args: list[str]) -> tuple[str | None, list[str]]:
    """(the value of --config, the other arguments); (None, args) without --config."""
    for i, arg in enumerate(args):
        if arg.startswith("--config="):
            return arg.split("=", 1)[1], args[:i] + args[i + 1 :]
        if arg == "--config":
            if i + 1 >= len(args):
                raise TvfError("--config needs a path: tvf train --config RUN/config.json")
            return args[i + 1], args[:i] + args[i + 2 :]
    return None, args


def _coerce(name: str, value: Any, hint: Any, path: Path) -> Any:
    """A JSON value of the saved config as the field's type; a wrong type is a one-line error."""
    options = typing.get_args(hint) or (hint,)
    if value is None and type(None) in options:
        return None
    for option in options:
        if option is Path and isinstance(value, str):
            return Path(value)
        if option is float and isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
        if option in (int, str, bool) and type(value) is option:
            return value
    wanted = " or ".join(getattr(o, "__name__", str(o)) for o in options)
    raise TvfError(f"{path}: train.{name} is {value!r}, not a {wanted}; restore the file or start a new run")


def saved_flags(path: Path, kind: str | None) -> tuple[str, _TrainFlags]:
    """The model kind of the run saved in ``path`` and its flags as a `tvf train KIND` command
    (``--resume`` and ``--restart`` off, ``--config`` set to ``path``); ``kind``, when given, must be the
    run's."""
    fix = "pass the config.json of a run made by `tvf train`"
    saved = read_json(path, fix)
    if (
        not isinstance(saved, dict)
        or saved.get("kind") not in KINDS
        or not isinstance(saved.get("train"), dict)
    ):
        raise TvfError(f"{path} is not the config of a `tvf train` run (no model kind and flags); {fix}")
    run_kind = saved["kind"]
    if kind is not None and kind != run_kind:
        raise TvfError(
            f"{path} is a {run_kind} run, not a {kind} one; relaunch it with `tvf train --config {path}`"
        )
    cls = KINDS[run_kind]
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(saved["train"]) - set(known))
    if unknown:
        raise TvfError(f"{path}: unknown training flag(s) {', '.join(unknown)}; was it made by another tvf?")
    values = {k: _coerce(k, v, hints[k], path) for k, v in saved["train"].items()}
    missing = [k for k, f in known.items() if k not in values and f.default is MISSING]
    if missing:
        raise TvfError(f"{path} lacks the training flag(s) {', '.join(missing)}; {fix}")
    return run_kind, cls(**{**values, "resume": False, "restart": False, "config": path})


def relaunch_command(args: list[str]) -> _TrainFlags | None:
    """`tvf train [KIND] --config RUN/config.json [FLAG ...]` parsed with the saved flags as defaults;
    None when ``args`` is no such command."""
    if not args or args[0] != "train":
        return None
    rest = args[1:]
    kind = rest[0] if rest and rest[0] in KINDS else None
    value, flags = split_config_flag(rest[1:] if kind else rest)
    if value is None:
        return None
    run_kind, defaults = saved_flags(Path(value), kind)
    return tyro.cli(
        KINDS[run_kind], args=flags, default=defaults, prog=f"tvf train {run_kind} --config {value}"
    )
