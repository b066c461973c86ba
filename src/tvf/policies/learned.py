"""Policies of the learned methods: the greedy GCTN and the TVF tree-search planner, plus the oracle."""

from __future__ import annotations

import numpy as np
import torch

from tvf.models.images import to_rgbh
from tvf.planning.actions import bin_action
from tvf.planning.search import Plan, PlannerConfig, TreeSearch
from tvf.policies.base import Observation


def observation_tensor(images: Observation, device: torch.device) -> torch.Tensor:
    """An observation dict -> normalised RGB-H (1, 4, H, W) on ``device``."""
    return to_rgbh(images["color"], images["height"]).to(device)


class OraclePolicy:
    """The scripted expert (the ceiling for learned methods); it reads the simulator it is given."""

    name = "oracle"

    def __init__(self, env) -> None:
        self.env = env

    def reset(self) -> None:
        pass

    def act(self, obs: Observation, goal: Observation) -> np.ndarray | None:
        return self.env.oracle_action()


class GctnPolicy:
    """Greedy GCTN: argmax pick, then argmax place and rotation at that pick."""

    name = "gctn"

    def __init__(self, model, device: torch.device | str = "cpu") -> None:
        self.device = torch.device(device)
        self.model = model.eval().to(self.device)

    def reset(self) -> None:
        pass

    def act(self, obs: Observation, goal: Observation) -> np.ndarray:
        current, target = observation_tensor(obs, self.device), observation_tensor(goal, self.device)
        pick, place, rot, _ = self.model.act(current, target)
        r = self.model.preset.n_rotations
        return bin_action(pick[0].cpu().numpy(), place[0].cpu().numpy(), int(rot[0]), r, obs["height"])


class TvfPolicy:
    """TVF: tree search over GCTN proposals and VF imagination; executes the first action of the best path.

    ``last_plan`` holds the newest search; with ``keep_images`` it keeps every imagined image (for GIFs).
    """

    def __init__(self, gctn, vf, config: PlannerConfig, device: torch.device | str = "cpu",
                 name: str = "tvf") -> None:  # fmt: skip
        self.name = name
        self.device = torch.device(device)
        self.search = TreeSearch(gctn.eval().to(self.device), vf.eval().to(self.device), config)
        self.last_plan: Plan | None = None
        self.keep_images = False

    def reset(self) -> None:
        self.last_plan = None

    def act(self, obs: Observation, goal: Observation) -> np.ndarray:
        current, target = observation_tensor(obs, self.device), observation_tensor(goal, self.device)
        plan = self.search.search(current, target, self.keep_images)
        self.last_plan = plan
        node = plan.first
        return bin_action(node.pick, node.place, node.rotation, self.search.n_rotations, obs["height"])
