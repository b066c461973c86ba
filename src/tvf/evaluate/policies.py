"""Policies that evaluation runs in closed loop: the oracle, the greedy GCTN and the TVF planners."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from tvf.errors import TvfError
from tvf.planning.actions import bin_action


def resolve_checkpoint(path: str | Path | None, kind: str = "gctn") -> Path:
    """A run directory (its checkpoints/last.pt), a checkpoint file, or None for the shipped weights."""
    if path is None:
        from tvf.weights import shipped_checkpoint

        return shipped_checkpoint(kind)
    path = Path(path)
    if path.is_dir():
        last = path / "checkpoints" / "last.pt"
        if not last.exists():
            raise TvfError(f"{path} holds no checkpoints/last.pt; pass a run directory made by `tvf train`")
        return last
    if not path.exists():
        raise TvfError(f"checkpoint {path} does not exist; pass a run directory or a .pt file")
    return path


def load_policy_model(path: str | Path | None, kind: str, device: str = "cpu"):
    """A model of ``kind`` (gctn | vf) in eval mode, from a run, a file or the shipped weights."""
    from tvf.models.checkpoint import load_model

    model, _ = load_model(resolve_checkpoint(path, kind), kind)
    return model.eval().to(device)


def _rgbh(images: dict, device: torch.device) -> torch.Tensor:
    from tvf.models.images import to_rgbh

    return to_rgbh(images["color"], images["height"]).to(device)


class OraclePolicy:
    """The scripted expert (the ceiling for learned methods)."""

    name = "oracle"

    def act(self, env, obs: dict, goal: dict) -> np.ndarray | None:
        return env.oracle_action()


class GctnPolicy:
    """Greedy GCTN: argmax pick, then argmax place and rotation at that pick."""

    name = "gctn"

    def __init__(self, checkpoint: str | Path | None, device: str = "cpu") -> None:
        self.model = load_policy_model(checkpoint, "gctn", device)
        self.device = torch.device(device)

    def act(self, env, obs: dict, goal: dict) -> np.ndarray:
        pick, place, rot, _ = self.model.act(_rgbh(obs, self.device), _rgbh(goal, self.device))
        r = self.model.preset.n_rotations
        return bin_action(pick[0].cpu().numpy(), place[0].cpu().numpy(), int(rot[0]), r, obs["height"])


class TvfPolicy:
    """TVF: tree search over GCTN proposals and VF imagination; executes the first action of the best path."""

    def __init__(self, gctn: str | Path | None, vf: str | Path | None, config, device: str = "cpu") -> None:
        from tvf.planning.search import TreeSearch

        self.device = torch.device(device)
        self.search = TreeSearch(
            load_policy_model(gctn, "gctn", device), load_policy_model(vf, "vf", device), config
        )
        self.last_plan = None
        self.keep_images = False

    def act(self, env, obs: dict, goal: dict) -> np.ndarray:
        plan = self.search.search(_rgbh(obs, self.device), _rgbh(goal, self.device), self.keep_images)
        self.last_plan = plan
        node = plan.first
        return bin_action(node.pick, node.place, node.rotation, self.search.n_rotations, obs["height"])
