"""Checkpoints and weights carry the SHA-256 of their content: a flipped byte anywhere in a `.pt`, a
`.safetensors` or its JSON config is harmless or a one-line CheckpointError naming the file (never other
weights, never another exception); a text file renamed `.pt` is one line; version 1 files (no hash)
load with a warning."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from tvf.models.checkpoint import (
    HASH,
    CheckpointError,
    content_sha256,
    load_checkpoint,
    save_checkpoint,
    save_weights,
)
from tvf.models.presets import SMOKE
from tvf.models.vf import VisualForesight
from tvf.weights import KINDS, WEIGHTS_DIR, config_path, shipped_name


def _same(a, b) -> bool:
    """Equal values of the same types, tensors bit for bit (NaN equals NaN)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, torch.Tensor):
        bits = [t.contiguous().reshape(-1).view(torch.uint8) for t in (a, b)]
        return a.dtype == b.dtype and a.shape == b.shape and torch.equal(*bits)
    if isinstance(a, dict):
        return list(a) == list(b) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def _view(ckpt) -> tuple:
    return ckpt.kind, ckpt.config, ckpt.step, ckpt.model, ckpt.optimizer, ckpt.extra


def _trained_vf() -> tuple[VisualForesight, torch.optim.Optimizer]:
    """A smoke VF after one Adam step (as `tvf train vf --preset smoke` checkpoints it)."""
    model = VisualForesight(SMOKE, seed=0)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    for p in model.parameters():
        p.grad = torch.full_like(p, 0.1)
    optimizer.step()
    return model, optimizer


def _flips(good: bytes, positions: int, masks: tuple[int, ...]):
    for mask in masks:
        for i in np.linspace(0, len(good) - 1, positions).astype(int):
            data = bytearray(good)
            data[i] ^= mask
            yield i, mask, bytes(data)


def _outcome(path: Path, reference: tuple, kind: str = "vf") -> str:
    try:
        loaded = load_checkpoint(path, kind)
    except CheckpointError as exc:
        assert "\n" not in str(exc) and path.stem in str(exc), exc
        return "reported"
    assert _same(_view(loaded), reference), "loaded other weights without an error"
    return "harmless"


def _sweep_checkpoint(tmp_path: Path, positions: int, masks: tuple[int, ...]) -> dict[str, int]:
    model, optimizer = _trained_vf()
    extra = {"data_fingerprint": "ab", "val": {"loss": 0.5}}
    source = save_checkpoint(tmp_path / "source.pt", model, optimizer, 3, extra=extra)
    reference, path = _view(load_checkpoint(source, "vf")), tmp_path / "last.pt"
    counts = {"harmless": 0, "reported": 0}
    for i, mask, data in _flips(source.read_bytes(), positions, masks):
        path.write_bytes(data)
        try:
            counts[_outcome(path, reference)] += 1
        except AssertionError as exc:
            raise AssertionError(f"byte {i} ^ {mask:#x}: {exc}") from None
    return counts


def _sweep_weights(tmp_path: Path, positions: int, masks: tuple[int, ...]) -> dict[str, int]:
    """Flips in the safetensors file, then in its JSON config."""
    source = save_weights(tmp_path / "src" / "vf-smoke.safetensors", _trained_vf()[0], 3, extra={"val": None})
    reference = _view(load_checkpoint(source, "vf"))
    path = tmp_path / "w" / source.name
    path.parent.mkdir()
    counts = {"harmless": 0, "reported": 0}
    for target in (path, config_path(path)):
        original = (source.parent / target.name).read_bytes()
        for other in (path, config_path(path)):
            other.write_bytes((source.parent / other.name).read_bytes())
        for i, mask, data in _flips(original, positions, masks):
            target.write_bytes(data)
            try:
                counts[_outcome(path, reference)] += 1
            except AssertionError as exc:
                raise AssertionError(f"{target.name} byte {i} ^ {mask:#x}: {exc}") from None
        target.write_bytes(original)
    return counts


def test_a_byte_flip_sweep_over_a_checkpoint_is_harmless_or_reported(tmp_path):
    counts = _sweep_checkpoint(tmp_path, 40, (0xFF,))
    assert sum(counts.values()) == 40 and counts["reported"] > 0


def test_a_byte_flip_sweep_over_weights_and_config_is_harmless_or_reported(tmp_path):
    counts = _sweep_weights(tmp_path, 20, (0xFF,))
    assert sum(counts.values()) == 40 and counts["reported"] > 0


@pytest.mark.slow
def test_the_full_byte_flip_sweep_over_a_checkpoint(tmp_path):
    counts = _sweep_checkpoint(tmp_path, 600, (0xFF, 0x01))
    print(f"checkpoint byte-flip sweep: {counts}")
    assert sum(counts.values()) == 1200 and counts["reported"] > 0


@pytest.mark.slow
def test_the_full_byte_flip_sweep_over_weights(tmp_path):
    counts = _sweep_weights(tmp_path, 300, (0xFF, 0x01))
    print(f"weights byte-flip sweep: {counts}")
    assert sum(counts.values()) == 1200 and counts["reported"] > 0


def test_a_text_file_renamed_pt_is_one_line(tmp_path):
    path = tmp_path / "notes.pt"
    path.write_text("experiment notes: lr 1e-4 was better\n")
    with pytest.raises(CheckpointError, match=r"notes\.pt is corrupt or not a tvf checkpoint") as info:
        load_checkpoint(path, "gctn")
    assert "\n" not in str(info.value)


def _nudge_a_weight(payload: dict) -> None:
    name = next(k for k, v in payload["model"].items() if v.is_floating_point())
    payload["model"][name].add_(1e-3)


def test_a_changed_tensor_or_setting_does_not_match_the_hash(tmp_path):
    model, optimizer = _trained_vf()
    path = save_checkpoint(tmp_path / "last.pt", model, optimizer, 2)
    payload = torch.load(path, weights_only=True)
    assert payload["version"] == 2
    assert payload[HASH] == content_sha256({k: v for k, v in payload.items() if k != HASH})
    changes = (
        _nudge_a_weight,
        lambda p: p.__setitem__("step", 3),
        lambda p: p["optimizer"]["param_groups"][0].__setitem__("lr", 2e-3),
    )
    for change in changes:
        changed = torch.load(path, weights_only=True)
        change(changed)
        torch.save(changed, tmp_path / "changed.pt")
        with pytest.raises(CheckpointError, match=r"changed\.pt does not match its SHA-256 .*damaged"):
            load_checkpoint(tmp_path / "changed.pt", "vf")
    del payload[HASH]
    torch.save(payload, tmp_path / "unhashed.pt")
    with pytest.raises(CheckpointError, match=r"unhashed\.pt has no SHA-256"):
        load_checkpoint(tmp_path / "unhashed.pt", "vf")


def test_other_tensors_beside_a_config_do_not_match_its_hash(tmp_path):
    a = save_weights(tmp_path / "a" / "vf-smoke.safetensors", VisualForesight(SMOKE, seed=0))
    b = save_weights(tmp_path / "b" / "vf-smoke.safetensors", VisualForesight(SMOKE, seed=1))
    a.write_bytes(b.read_bytes())  # same names and shapes, other values
    with pytest.raises(
        CheckpointError, match=r"vf-smoke\.safetensors do not match the SHA-256 of their tensors"
    ):
        load_checkpoint(a, "vf")
    meta = json.loads(config_path(b).read_text())
    meta["step"] = 7
    config_path(b).write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match=r"vf-smoke\.json does not match its SHA-256"):
        load_checkpoint(b, "vf")


def test_version_1_files_load_unverified_with_one_warning(tmp_path, capsys):
    model, optimizer = _trained_vf()
    payload = torch.load(save_checkpoint(tmp_path / "new.pt", model, optimizer, 2), weights_only=True)
    del payload[HASH]
    payload["version"] = 1
    torch.save(payload, tmp_path / "old.pt")
    weights = save_weights(tmp_path / "vf-smoke.safetensors", model, 2)
    meta = json.loads(config_path(weights).read_text())
    del meta[HASH]
    meta["version"] = 1
    config_path(weights).write_text(json.dumps(meta))
    for path in (tmp_path / "old.pt", weights):
        for _ in range(2):
            ckpt = load_checkpoint(path, "vf")
        assert all(torch.equal(ckpt.model[k], v) for k, v in model.state_dict().items())
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(path) in err[0] and "loaded unverified" in err[0], err


def test_the_shipped_weights_carry_their_hashes_and_a_flipped_byte_is_reported(tmp_path, capsys):
    for kind in KINDS:
        source = WEIGHTS_DIR / shipped_name(kind)
        meta = json.loads(config_path(source).read_text())
        assert meta["version"] == 2 and set(meta[HASH]) == {"tensors", "config"}
        reference = load_checkpoint(source, kind)
        assert not capsys.readouterr().err  # verified, no warning
        copy = tmp_path / source.name
        config_path(copy).write_bytes(config_path(source).read_bytes())
        data = bytearray(source.read_bytes())
        data[len(data) // 2] ^= 0x10  # one bit of one weight (the "bias off by 42.7")
        copy.write_bytes(bytes(data))
        with pytest.raises(CheckpointError, match=rf"{copy.name} do not match the SHA-256 of their tensors"):
            load_checkpoint(copy, kind)
        copy.write_bytes(source.read_bytes())
        assert _same(_view(load_checkpoint(copy, kind)), _view(reference))
