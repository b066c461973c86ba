"""Policies of the learned methods: the greedy GCTN and the TVF tree-search planner, plus the oracle."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from tvf.device import mixes_environments
from tvf.models.images import to_rgbh
from tvf.planning.actions import bin_action, refining_height
from tvf.planning.search import Plan, PlannerConfig, TreeSearch
from tvf.planning.simulated import SimulatedSearch
from tvf.policies.base import Observation


def observation_tensor(images: Observation, device: torch.device) -> torch.Tensor:
    """An observation dict -> normalised RGB-H (1, 4, H, W) on ``device``."""
    return to_rgbh(images["color"], images["height"]).to(device)


def observations_tensor(images: Sequence[Observation], device: torch.device) -> torch.Tensor:
    """Observation dicts -> normalised RGB-H (N, 4, H, W) on ``device``."""
    return torch.cat([observation_tensor(x, device) for x in images])


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

    def __init__(self, model, device: torch.device | str = "cpu", refine_yaw: bool = False) -> None:
        self.device = torch.device(device)
        self.model = model.eval().to(self.device)
        self.refine_yaw = refine_yaw
        """Correct the place's turn to the block yaws read from the height maps (tvf.planning.yaw)."""
        self.mix: bool | None = None
        """Batch several environments in one GCTN pass (None: where the device does, a GPU)."""

    def reset(self) -> None:
        pass

    def act(self, obs: Observation, goal: Observation) -> np.ndarray:
        current, target = observation_tensor(obs, self.device), observation_tensor(goal, self.device)
        return self._act(current, target, [obs], [goal])[0]

    def act_batch(
        self, observations: Sequence[Observation], goals: Sequence[Observation]
    ) -> list[np.ndarray]:
        """The greedy action of every pair: one GCTN pass over all of them where the device batches across
        environments (a GPU), else one per pair, bit-identical to :meth:`act` (the CPU,
        :func:`tvf.device.mixes_environments`)."""
        if not (self.mix if self.mix is not None else mixes_environments(self.device)):
            return [self.act(obs, goal) for obs, goal in zip(observations, goals, strict=True)]
        current, target = (
            observations_tensor(observations, self.device),
            observations_tensor(goals, self.device),
        )
        return self._act(current, target, observations, goals)

    def _act(self, current: torch.Tensor, goal: torch.Tensor, observations: Sequence[Observation],
             goals: Sequence[Observation]) -> list:  # fmt: skip
        pick, place, rot, _ = self.model.act(current, goal)
        pick, place, r = pick.cpu().numpy(), place.cpu().numpy(), self.model.preset.n_rotations
        refine = self.refine_yaw
        return [
            bin_action(pick[i], place[i], int(rot[i]), r, obs["height"], refining_height(goal, refine))
            for i, (obs, goal) in enumerate(zip(observations, goals, strict=True))
        ]


class TvfPolicy:
    """TVF: tree search over GCTN proposals and VF imagination; executes the first action of the best path.

    ``last_plan`` holds the newest search; with ``keep_images`` it keeps every imagined image (for GIFs).
    """

    def __init__(self, gctn, vf, config: PlannerConfig, device: torch.device | str = "cpu",
                 name: str = "tvf", refine_yaw: bool = False) -> None:  # fmt: skip
        self.name = name
        self.refine_yaw = refine_yaw
        """Correct the executed turn to the block yaws read from the height maps (tvf.planning.yaw)."""
        self.device = torch.device(device)
        self.search = TreeSearch(gctn.eval().to(self.device), vf.eval().to(self.device), config)
        self.last_plan: Plan | None = None
        self.keep_images = False

    def reset(self) -> None:
        self.last_plan = None

    def act(self, obs: Observation, goal: Observation) -> np.ndarray:
        return self.act_batch([obs], [goal])[0]

    def act_batch(
        self, observations: Sequence[Observation], goals: Sequence[Observation]
    ) -> list[np.ndarray]:
        """The chosen action of each pair's plan (its first, polished where the planner polishes), from
        one search over all the roots
        (:meth:`~tvf.planning.search.TreeSearch.search_many`); ``last_plan`` is the last pair's plan."""
        current, target = (
            observations_tensor(observations, self.device),
            observations_tensor(goals, self.device),
        )
        plans = self.search.search_many(current, target, self.keep_images)
        self.last_plan = plans[-1]
        n = self.search.n_rotations
        return [
            bin_action(
                p.chosen.pick,
                p.chosen.place,
                p.chosen.rotation,
                n,
                obs["height"],
                refining_height(goal, self.refine_yaw),
            )
            for p, obs, goal in zip(plans, observations, goals, strict=True)
        ]


class SimulatedTvfPolicy:
    """TVF with the simulator as its foresight (:mod:`tvf.planning.simulated`): every proposal of the
    search is executed in ``env``, the environment the policy acts in, and undone. An upper bound for
    research: a decision costs one simulator step per node (39 for TVF-L). With ``executed`` levels
    only the first ones are executed and the rest imagined by ``proposer``'s VF."""

    def __init__(self, env, proposer: TreeSearch, name: str = "tvf", refine_yaw: bool = False,
                 executed: int | None = None) -> None:  # fmt: skip
        self.name = name
        self.search = SimulatedSearch(proposer, env, refine_yaw, executed)
        self.last_plan: Plan | None = None
        self.keep_images = False

    def reset(self) -> None:
        self.last_plan = None

    def act(self, obs: Observation, goal: Observation) -> np.ndarray:
        self.last_plan, actions = self.search.search(obs, goal, self.keep_images)
        return actions[self.last_plan.path[0].index]
