"""Checkpoints: round trip, atomic write, and one clear error for every bad file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from tvf.errors import TvfError
from tvf.models.checkpoint import (
    CheckpointError,
    load_checkpoint,
    load_initial_weights,
    load_model,
    save_checkpoint,
)
from tvf.models.gctn import GCTN
from tvf.models.presets import LITE, SMOKE
from tvf.models.vf import VisualForesight


def _trained_vf(steps: int = 2) -> tuple[VisualForesight, torch.optim.Optimizer]:
    model = VisualForesight(SMOKE)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    rgbh = torch.randn(1, 4, 160, 160, generator=torch.Generator().manual_seed(0))
    for _ in range(steps):
        optimizer.zero_grad()
        model.loss(rgbh, torch.tensor([[50, 50]]), torch.tensor([[90, 90]]), torch.zeros(1), rgbh).backward()
        optimizer.step()
    return model, optimizer


def test_round_trip(tmp_path: Path) -> None:
    model, optimizer = _trained_vf()
    path = save_checkpoint(tmp_path / "vf" / "last.pt", model, optimizer, step=7, extra={"loss": 0.5})
    assert sorted(p.name for p in path.parent.iterdir()) == ["last.pt"]  # no temporary file left behind

    fresh = VisualForesight(SMOKE)
    fresh_optimizer = torch.optim.Adam(fresh.parameters(), lr=1e-3)
    ckpt = load_checkpoint(path, "vf", model=fresh, optimizer=fresh_optimizer)
    assert ckpt.step == 7 and ckpt.extra == {"loss": 0.5} and ckpt.kind == "vf"
    for a, b in zip(model.state_dict().values(), fresh.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b)
    assert fresh_optimizer.state_dict()["state"][0]["step"] == optimizer.state_dict()["state"][0]["step"]

    rebuilt, _ = load_model(path, "vf")
    assert isinstance(rebuilt, VisualForesight) and rebuilt.preset == SMOKE


def test_wrong_kind_names_file_and_fix(tmp_path: Path) -> None:
    path = save_checkpoint(tmp_path / "gctn.pt", GCTN(SMOKE), step=1)
    with pytest.raises(CheckpointError, match=r"gctn\.pt.*'gctn' model, expected 'vf'.*pass a vf checkpoint"):
        load_checkpoint(path, "vf")


def test_incompatible_config(tmp_path: Path) -> None:
    path = save_checkpoint(tmp_path / "vf.pt", VisualForesight(SMOKE))
    with pytest.raises(CheckpointError, match=r"vf\.pt.*another config.*preset\.name"):
        load_checkpoint(path, "vf", model=VisualForesight(LITE))


def test_initial_weights_accept_older_configs_and_free_fields_only(tmp_path: Path) -> None:
    model, _ = _trained_vf()
    older = model.config()
    del older["preset"]["vf_head"]  # a file written before the field existed (the shipped lite VF)
    path = save_checkpoint(tmp_path / "vf.pt", model, step=3, config=older)
    with pytest.raises(CheckpointError, match="vf_head"):
        load_checkpoint(path, "vf", model=VisualForesight(SMOKE))  # a resume stays exact
    local = VisualForesight(SMOKE.replace(vf_head="local"))
    assert load_initial_weights(local, path, "vf", free=("vf_head",)).step == 3
    for a, b in zip(model.state_dict().values(), local.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b)
    with pytest.raises(CheckpointError, match="vf_head"):
        load_initial_weights(VisualForesight(SMOKE.replace(vf_head="local")), path, "vf")  # not freed
    with pytest.raises(CheckpointError, match=r"another config.*preset\.name"):
        load_initial_weights(VisualForesight(LITE), path, "vf", free=("vf_head",))


@pytest.mark.parametrize("content", [None, b"", b"not a checkpoint at all", "truncated"])
def test_missing_or_corrupt_file(tmp_path: Path, content: bytes | str | None) -> None:
    path = tmp_path / "bad.pt"
    if content == "truncated":
        save_checkpoint(path, VisualForesight(SMOKE))
        path.write_bytes(path.read_bytes()[:200])
    elif content is not None:
        path.write_bytes(content)
    with pytest.raises(CheckpointError, match=r"bad\.pt") as info:
        load_checkpoint(path, "vf")
    assert isinstance(info.value, TvfError)


def test_foreign_torch_file(tmp_path: Path) -> None:
    path = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, path)
    with pytest.raises(CheckpointError, match=r"foreign\.pt is not a tvf checkpoint"):
        load_checkpoint(path, "gctn")


def test_extra_must_be_plain_data(tmp_path: Path) -> None:
    with pytest.raises(TypeError, match=r"extra\['rng'\] is a ndarray"):
        save_checkpoint(tmp_path / "vf.pt", VisualForesight(SMOKE), extra={"rng": np.zeros(3)})
    assert not list(tmp_path.iterdir())


def test_written_files_are_readable_by_others(tmp_path):
    import stat

    from tvf.models.checkpoint import save_checkpoint
    from tvf.models.gctn import GCTN
    from tvf.models.presets import get_preset
    from tvf.viz.images import atomic_write_bytes

    save_checkpoint(tmp_path / "m.pt", GCTN(get_preset("smoke")))
    atomic_write_bytes(tmp_path / "r.md", b"x")
    for name in ("m.pt", "r.md"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644
