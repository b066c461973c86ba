"""Weights as safetensors + JSON config: round trip without pickle, one-line errors, the shipped files."""

from __future__ import annotations

import json
import pickle
import shutil
from pathlib import Path

import pytest
import torch

import tvf
from tvf.models.checkpoint import (
    CheckpointError,
    export_weights,
    load_checkpoint,
    load_model,
    load_trained,
    save_checkpoint,
    save_weights,
)
from tvf.models.gctn import GCTN
from tvf.models.presets import SMOKE
from tvf.models.vf import VisualForesight
from tvf.runs import RunDir
from tvf.weights import KINDS, WEIGHTS_DIR, config_path, provenance, sha256_file, shipped_files, shipped_name


def _no_pickle(monkeypatch) -> None:
    def refuse(*args, **kwargs):
        raise AssertionError("weights must load without torch.load / pickle")

    for module, name in ((torch, "load"), (pickle, "load"), (pickle, "loads"), (pickle, "Unpickler")):
        monkeypatch.setattr(module, name, refuse)


def test_round_trip_without_pickle(tmp_path: Path, monkeypatch) -> None:
    model = GCTN(SMOKE, seed=3)
    path = save_weights(tmp_path / "w" / "gctn-smoke.safetensors", model, 5, extra={"val": {"loss": 1.5}})
    assert sorted(p.name for p in path.parent.iterdir()) == ["gctn-smoke.json", "gctn-smoke.safetensors"]
    meta = json.loads(config_path(path).read_text())
    assert (meta["format"], meta["version"], meta["kind"]) == ("tvf-weights", 2, "gctn")
    assert meta["model_class"] == "GCTN" and meta["tvf_version"] == tvf.__version__
    assert meta["config"] == model.config() and meta["step"] == 5 and meta["weights"] == path.name
    assert meta["parameters"] == sum(p.numel() for p in model.parameters())
    _no_pickle(monkeypatch)
    rebuilt, ckpt = load_model(path, "gctn")
    assert ckpt.step == 5 and ckpt.optimizer is None and ckpt.extra == {"val": {"loss": 1.5}}
    for key, value in model.state_dict().items():
        assert torch.equal(rebuilt.state_dict()[key], value), key


def test_old_checkpoints_still_load_and_export_to_the_same_weights(tmp_path: Path) -> None:
    model = VisualForesight(SMOKE, seed=1)
    run = RunDir(tmp_path / "run")
    old = save_checkpoint(run.last, model, torch.optim.Adam(model.parameters()), step=4, extra={"val": None})
    from_run = export_weights(run.root, "vf", tmp_path / "a" / "vf-smoke.safetensors")
    from_file = export_weights(old, "vf", tmp_path / "b" / "vf-smoke.safetensors")
    assert from_run.read_bytes() == from_file.read_bytes()  # the same bytes every time: stable hashes
    a, b = load_checkpoint(old, "vf"), load_checkpoint(from_run, "vf")
    assert a.optimizer is not None and b.optimizer is None and a.step == b.step == 4
    assert all(torch.equal(a.model[k], b.model[k]) for k in a.model)


def _one_line(info) -> str:
    message = str(info.value)
    assert "\n" not in message
    return message


def test_wrong_corrupt_or_incomplete_weights_are_one_line_errors(tmp_path: Path) -> None:
    gctn = save_weights(tmp_path / "gctn.safetensors", GCTN(SMOKE))
    with pytest.raises(CheckpointError, match=r"gctn\.safetensors holds a 'gctn' model, expected 'vf'") as e:
        load_model(gctn, "vf")
    _one_line(e)
    bad = tmp_path / "bad.safetensors"
    shutil.copy(config_path(gctn), config_path(bad))
    for data in (gctn.read_bytes()[:1000], b"", b"\xff" * 64):
        bad.write_bytes(data)
        with pytest.raises(CheckpointError, match=r"bad\.safetensors are corrupt or not safetensors") as e:
            load_model(bad, "gctn")
        _one_line(e)
    lone = tmp_path / "lone.safetensors"
    shutil.copy(gctn, lone)
    with pytest.raises(CheckpointError, match=r"lone\.safetensors have no config lone\.json"):
        load_model(lone, "gctn")
    config_path(lone).write_text("{")
    with pytest.raises(CheckpointError, match=r"lone\.json is not valid JSON"):
        load_model(lone, "gctn")
    vf = save_weights(tmp_path / "vf.safetensors", VisualForesight(SMOKE))
    shutil.copy(config_path(gctn), config_path(vf))  # a GCTN config beside VF tensors
    with pytest.raises(CheckpointError, match=r"vf\.safetensors hold a 'vf' model but vf\.json describes"):
        load_model(vf, "gctn")
    with pytest.raises(CheckpointError, match="must end in .safetensors"):
        save_weights(tmp_path / "x.pt", GCTN(SMOKE))


def test_the_shipped_folder_holds_safetensors_that_match_their_hashes(monkeypatch) -> None:
    assert sorted(p.name for p in WEIGHTS_DIR.iterdir() if p.suffix != ".py" and p.is_file()) == sorted(
        shipped_files()
    )  # no .pt left
    record = provenance()
    for kind in KINDS:
        entry = record["models"][kind]
        assert entry["file"] == shipped_name(kind) and entry["config"] == config_path(entry["file"]).name
        assert entry["sha256"] == {n: sha256_file(WEIGHTS_DIR / n) for n in (entry["file"], entry["config"])}
    _no_pickle(monkeypatch)
    model = load_trained(None, "vf")
    assert sum(p.numel() for p in model.parameters()) == record["models"]["vf"]["parameters"]
