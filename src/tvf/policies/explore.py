"""A searching method's own moves, recorded as foresight data (``tvf demos --moves METHOD``).

The TVF search imagines the outcome of every proposal it makes, but the VF learns from demonstrations,
which hold only the expert's moves. :class:`ProposalExplorer` executes, at every step, one of the
method's root proposals drawn uniformly with a seeded generator: its episodes walk the branches the
search considers, so their transitions are the moves the VF is asked to imagine (docs/data.md, "The
planner's own moves").
"""

from __future__ import annotations

from functools import cache

import numpy as np
import torch

from tvf.errors import TvfError
from tvf.planning.actions import refining_height
from tvf.planning.search import TreeSearch
from tvf.policies.base import Observation
from tvf.policies.learned import observation_tensor
from tvf.policies.registry import (
    PLANNER_METHODS,
    PolicySpec,
    get_method,
    load_gctn,
    planner_of,
    refine_yaw_of,
)

MOVES_STREAM = 6
"""The child of ``SeedSequence(seed)`` that draws an episode's proposals (0-2: the environment, 3: the
random steps, 5: the near misses)."""


def moves_rng(seed: int) -> np.random.Generator:
    """The generator that draws episode ``seed``'s proposals."""
    return np.random.default_rng(np.random.SeedSequence(seed).spawn(MOVES_STREAM + 1)[MOVES_STREAM])


class ProposalExplorer:
    """Executes one of ``search``'s root proposals, drawn uniformly by ``rng``, at every step."""

    def __init__(self, search: TreeSearch, rng: np.random.Generator, refine_yaw: bool = False) -> None:
        self.search, self.rng, self.refine_yaw = search, rng, refine_yaw

    def reset(self) -> None:
        pass

    @torch.no_grad()
    def act(self, obs: Observation, goal: Observation) -> np.ndarray:
        device = next(self.search.gctn.parameters()).device
        current, target = observation_tensor(obs, device), observation_tensor(goal, device)
        _, _, actions = self.search.propose_actions(current, target, obs["height"],
                                                    refining_height(goal, self.refine_yaw))  # fmt: skip
        return actions[int(self.rng.integers(len(actions)))]


def check_moves_method(method: str) -> None:
    """A method whose root proposals can be explored, else a one-line error naming the choices."""
    if get_method(method).planner is None:
        raise TvfError(f"--moves {method}: only a searching method has proposals to explore; choose one of "
                       f"{', '.join(PLANNER_METHODS)}")  # fmt: skip


@cache
def _proposer(method: str) -> tuple[TreeSearch, bool]:
    """The method's search (its shipped GCTN, its planner; no VF: proposals only), loaded once a process."""
    check_moves_method(method)
    spec = PolicySpec(method, device="cpu")
    return TreeSearch(load_gctn(spec).eval(), None, planner_of(spec)), refine_yaw_of(spec)


def proposal_mover(method: str, seed: int) -> ProposalExplorer:
    """The explorer of ``method``'s root proposals for episode ``seed`` (its own generator)."""
    search, refine_yaw = _proposer(method)
    return ProposalExplorer(search, moves_rng(seed), refine_yaw)
