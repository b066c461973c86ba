"""The policy contract: what every method that acts in closed loop implements.

An observation (and a goal) is a dict of plain arrays: ``color`` uint8 (H, W, 3) and ``height`` float32
(H, W) in metres, the top-down RGB-H image of docs/observation.md. An action is a ``(2, 4)`` array of
pick and place poses (x, y, z, yaw) in the robot base frame, or None when the policy has nothing to do.
No policy needs the simulator: the oracle, which does, keeps its environment inside.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from tvf.envs import Observation

__all__ = ["Observation", "Policy"]


@runtime_checkable
class Policy(Protocol):
    """A closed-loop policy: ``reset()`` before an episode, then ``act(obs, goal)`` once per step."""

    name: str

    def reset(self) -> None:
        """Forget anything kept from the previous episode."""

    def act(self, obs: Observation, goal: Observation) -> np.ndarray | None:
        """The next ``(2, 4)`` pick-and-place action, or None to stop."""
