"""Policies that evaluation runs in closed loop: the oracle and the GCTN (TVF planners join later)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from tvf.errors import TvfError
from tvf.planning.actions import bin_action


def resolve_checkpoint(path: str | Path) -> Path:
    """A run directory (its checkpoints/last.pt) or a checkpoint file."""
    path = Path(path)
    if path.is_dir():
        last = path / "checkpoints" / "last.pt"
        if not last.exists():
            raise TvfError(f"{path} holds no checkpoints/last.pt; pass a run directory made by `tvf train`")
        return last
    if not path.exists():
        raise TvfError(f"checkpoint {path} does not exist; pass a run directory or a .pt file")
    return path


class OraclePolicy:
    """The scripted expert (the ceiling for learned methods)."""

    name = "oracle"

    def act(self, env, obs: dict, goal: dict) -> np.ndarray | None:
        return env.oracle_action()


class GctnPolicy:
    """Greedy GCTN: argmax pick, then argmax place and rotation at that pick."""

    name = "gctn"

    def __init__(self, checkpoint: str | Path, device: str = "cpu") -> None:
        from tvf.models.checkpoint import load_model

        self.model, self.checkpoint = load_model(resolve_checkpoint(checkpoint), "gctn")
        self.model.eval().to(device)
        self.device = torch.device(device)

    def act(self, env, obs: dict, goal: dict) -> np.ndarray:
        from tvf.models.images import to_rgbh

        current = to_rgbh(obs["color"], obs["height"]).to(self.device)
        target = to_rgbh(goal["color"], goal["height"]).to(self.device)
        pick, place, rot, _ = self.model.act(current, target)
        r = self.model.preset.n_rotations
        return bin_action(pick[0].cpu().numpy(), place[0].cpu().numpy(), int(rot[0]), r, obs["height"])
