"""The policy contract: what every method that acts in closed loop implements.

An observation (and a goal) is a dict of plain arrays: ``color`` uint8 (H, W, 3) and ``height`` float32
(H, W) in metres, the top-down RGB-H image of docs/observation.md. An action is a ``(2, 4)`` array of
pick and place poses (x, y, z, yaw) in the robot base frame, or None when the policy has nothing to do.
No policy needs the simulator: the oracle, which does, keeps its environment inside.

A policy may also offer ``act_batch(observations, goals)``: the actions of several environments at once
(one model pass for all of them); :func:`act_all` uses it where it can and calls ``act`` otherwise.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from tvf.envs import Observation

__all__ = ["BatchPolicy", "Observation", "Policy", "act_all"]


@runtime_checkable
class Policy(Protocol):
    """A closed-loop policy: ``reset()`` before an episode, then ``act(obs, goal)`` once per step."""

    name: str

    def reset(self) -> None:
        """Forget anything kept from the previous episode."""

    def act(self, obs: Observation, goal: Observation) -> np.ndarray | None:
        """The next ``(2, 4)`` pick-and-place action, or None to stop."""


@runtime_checkable
class BatchPolicy(Policy, Protocol):
    """A policy that decides for several environments at once, each the action ``act`` would give."""

    def act_batch(self, observations: Sequence[Observation], goals: Sequence[Observation]) -> list:
        """One ``act(obs, goal)`` result per (observation, goal) pair, in order."""


def act_all(
    policies: Sequence[Policy], observations: Sequence[Observation], goals: Sequence[Observation]
) -> list[np.ndarray | None]:
    """The next action of every environment: environment ``i`` is driven by ``policies[i]``. Environments
    that share one :class:`BatchPolicy` object get their actions from one ``act_batch`` call."""
    actions: list[np.ndarray | None] = [None] * len(policies)
    groups: dict[int, list[int]] = {}
    for i, policy in enumerate(policies):
        groups.setdefault(id(policy), []).append(i)
    for rows in groups.values():
        policy = policies[rows[0]]
        if len(rows) > 1 and isinstance(policy, BatchPolicy):
            got = policy.act_batch([observations[i] for i in rows], [goals[i] for i in rows])
        else:
            got = [policy.act(observations[i], goals[i]) for i in rows]
        for i, action in zip(rows, got, strict=True):
            actions[i] = action
    return actions
