"""The model registry: per model kind its network class, sampler, training job, default recipe per preset
and shipped file name, in one place.

`tvf train KIND --preset P` trains with ``KINDS[KIND].recipes[P]`` unless a flag overrides a field, so
`tvf train gctn --preset lite` trains exactly the shipped lite recipe; the experiment reads the same
recipes. Adding a model kind: a class with ``checkpoint_kind`` (tvf.models.checkpoint.MODEL_CLASSES), a
sampler (tvf.data.samplers), a job (tvf.train.jobs) and an entry here: in MODELS when the experiment
trains and ships it, in BASELINES when it is trained for comparison only.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields, replace

from torch import nn

from tvf.data.samplers import GctnSampler, VfSampler
from tvf.errors import TvfError
from tvf.models.checkpoint import MODEL_CLASSES
from tvf.train.jobs import gctn_job, latent_job, vf_job
from tvf.train.trainer import TrainConfig, TrainingJob, check_config
from tvf.weights import shipped_name


@dataclass(frozen=True)
class Recipe:
    """A training schedule: optimiser steps, batch, (peak) learning rate, schedule and warm-up."""

    steps: int
    batch: int
    lr: float
    schedule: str = "constant"
    warmup: int = 0
    vf_changed_weight: float = 0.0
    """The VF's extra loss weight on changed pixels (0: the reference's loss; unused by the GCTN)."""
    vf_rollout: int = 1
    """The VF's rollout loss horizon in steps (1: the reference's one-step loss; unused by the GCTN)."""


@dataclass(frozen=True)
class ModelKind:
    name: str
    model_class: type[nn.Module]
    sampler_class: type
    job: Callable[[TrainConfig, type], TrainingJob]
    """``job(cfg, sampler_class)``: the model, its batches, loss and validation."""
    recipes: dict[str, Recipe]
    """The default recipe of each preset (lite: what the shipped weights were trained with)."""

    def shipped_file(self, preset: str) -> str:
        return shipped_name(self.name, preset)


VF_RECIPES = {"lite": Recipe(3000, 8, 1e-4), "paper": Recipe(60000, 1, 1e-4), "smoke": Recipe(2, 2, 1e-3)}
VF_TUNES: dict[str, tuple[Recipe, str]] = {
    # lite: the shipped VF (session 25, docs/results.md "A VF that meets the foresight targets"): the
    # recipe's VF fine-tuned through three-step rollouts, changed pixels weighted 21 times, the local head
    "lite": (Recipe(3000, 8, 2e-4, "cosine", 100, vf_changed_weight=20.0, vf_rollout=3), "local"),
    "smoke": (Recipe(2, 2, 1e-3, vf_changed_weight=20.0, vf_rollout=2), "local"),
}
"""The VF's second phase per preset, with its head (`tvf experiment --vf-tune`): it starts from the
weights of the recipe above (``--init``), with a fresh optimiser."""
MODELS: dict[str, ModelKind] = {
    "gctn": ModelKind(
        "gctn", MODEL_CLASSES["gctn"], GctnSampler, gctn_job,
        {
            # lite: about 90 minutes on 2 cores (docs/results.md)
            "lite": Recipe(21000, 2, 2e-4, "cosine", 500),
            # paper: the reference's schedule (batch 1, constant learning rate)
            "paper": Recipe(40000, 1, 1e-4),
            "smoke": Recipe(2, 2, 1e-3),
        },
    ),
    "vf": ModelKind(
        "vf", MODEL_CLASSES["vf"], VfSampler, vf_job,
        VF_RECIPES,
    ),
}  # fmt: skip
"""The kinds `tvf experiment` trains, evaluates and ships (tvf.weights.KINDS)."""
BASELINES: dict[str, ModelKind] = {
    # the latent-dynamics baseline of the foresight table: the VF's data and schedule
    "latent": ModelKind("latent", MODEL_CLASSES["latent"], VfSampler, latent_job, VF_RECIPES),
}
"""Kinds trained for comparison only (`tvf train KIND`, `tvf eval-vf --latent RUN`): no shipped weights."""
KINDS: dict[str, ModelKind] = {**MODELS, **BASELINES}
RECIPE_FIELDS = tuple(f.name for f in fields(Recipe))


def get_kind(name: str) -> ModelKind:
    if name not in KINDS:
        raise TvfError(f"unknown model kind {name!r}; choose one of {', '.join(KINDS)}")
    return KINDS[name]


def recipe(kind: str, preset: str) -> Recipe:
    """The default recipe of ``kind`` at ``preset``; an unknown preset is a one-line error."""
    recipes = get_kind(kind).recipes
    if preset not in recipes:
        raise TvfError(f"unknown preset {preset!r}; choose one of {', '.join(recipes)}")
    return recipes[preset]


def vf_tune(preset: str) -> tuple[Recipe, str]:
    """The VF's fine-tuning phase at ``preset`` and its head; a preset without one is a one-line error."""
    if preset not in VF_TUNES:
        raise TvfError(f"--vf-tune has no fine-tuning recipe for preset {preset!r} (it has: "
                       f"{', '.join(VF_TUNES)}); drop --vf-tune or use one of those")  # fmt: skip
    return VF_TUNES[preset]


def with_recipe(cfg: TrainConfig, kind: str) -> TrainConfig:
    """``cfg`` with every recipe field left unset (None) taken from the preset's recipe."""
    base = recipe(kind, cfg.preset)
    return replace(cfg, **{f: getattr(base, f) for f in RECIPE_FIELDS if getattr(cfg, f) is None})


def training_job(cfg: TrainConfig, kind: str) -> tuple[TrainConfig, TrainingJob]:
    """The resolved config and the job of a `tvf train KIND` run (the config is checked before the data
    is read)."""
    cfg = with_recipe(cfg, kind)
    check_config(cfg)
    spec = get_kind(kind)
    return cfg, spec.job(cfg, spec.sampler_class)
