"""The model registry: a preset owns its recipe, and `tvf train KIND --preset P` trains exactly it."""

from dataclasses import asdict, fields
from pathlib import Path

import pytest

from tvf.errors import TvfError
from tvf.models.checkpoint import MODEL_CLASSES
from tvf.models.presets import PRESETS
from tvf.train.registry import (
    BASELINES,
    KINDS,
    MODELS,
    RECIPE_FIELDS,
    Recipe,
    get_kind,
    recipe,
    vf_tune,
    with_recipe,
)
from tvf.train.trainer import TrainConfig
from tvf.weights import provenance, shipped_name


def test_every_kind_has_a_class_a_sampler_a_job_and_a_recipe_per_preset():
    assert set(MODELS) == {"gctn", "vf"} and set(BASELINES) == {"latent"}  # the experiment trains MODELS
    assert set(KINDS) == set(MODEL_CLASSES) == set(MODELS) | set(BASELINES)
    for name, kind in KINDS.items():
        assert kind.model_class is MODEL_CLASSES[name] and get_kind(name) is kind
        assert set(kind.recipes) == set(PRESETS)
    for name, kind in MODELS.items():
        assert kind.shipped_file("lite") == shipped_name(name) == f"{name}-lite.safetensors"
        assert kind.shipped_file("paper") == f"{name}-paper.safetensors"
    # the latent baseline: the VF's data (sampler) and schedule, nothing shipped
    assert BASELINES["latent"].sampler_class is MODELS["vf"].sampler_class
    assert BASELINES["latent"].recipes == MODELS["vf"].recipes
    with pytest.raises(TvfError, match="no shipped weights of kind 'latent'"):
        BASELINES["latent"].shipped_file("lite")


@pytest.mark.parametrize("kind", ["gctn", "vf"])
def test_the_lite_recipe_is_the_one_the_shipped_weights_were_trained_with(kind):
    trained = provenance()["models"][kind]["train"]
    older = {f.name: f.default for f in fields(Recipe)}  # a field a run predates had its default value
    expected = recipe(kind, "lite")
    if trained.get("init"):  # a second phase from other weights: `tvf experiment --vf-tune`'s recipe
        expected, head = vf_tune("lite")
        assert kind == "vf" and trained["vf_head"] == head
    assert {f: older[f] if trained.get(f) is None else trained[f] for f in RECIPE_FIELDS} == asdict(expected)


def test_unset_flags_take_the_recipe_and_given_flags_win():
    cfg = TrainConfig(data=Path("d"), out=Path("o"), preset="lite")
    gctn = with_recipe(cfg, "gctn")
    assert (gctn.steps, gctn.batch, gctn.lr, gctn.schedule, gctn.warmup) == (21000, 2, 2e-4, "cosine", 500)
    vf = with_recipe(cfg, "vf")
    assert (vf.steps, vf.batch, vf.schedule) == (3000, 8, "constant")
    mine = with_recipe(TrainConfig(data=Path("d"), out=Path("o"), preset="lite", steps=50, lr=1e-3), "gctn")
    assert (mine.steps, mine.lr, mine.batch, mine.schedule) == (50, 1e-3, 2, "cosine")
    with pytest.raises(TvfError, match="unknown preset 'huge'"):
        with_recipe(TrainConfig(data=Path("d"), out=Path("o"), preset="huge"), "gctn")
    with pytest.raises(TvfError, match="unknown model kind"):
        recipe("ldm", "lite")
