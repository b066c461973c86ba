"""The environment seam: what the episode loop needs from a world, simulated or real.

The simulator (:class:`tvf.sim.env.TvfEnv`, made by :class:`tvf.sim.factory.SimEnvFactory`) is the first
implementation; a real robot, a camera-noise wrapper or a vector of environments implements the same
two calls and plugs into :func:`tvf.evaluate.runner.run_episode` and `tvf eval` without touching the loop.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from tvf.tasks import Task

Observation = dict[str, np.ndarray]
"""``{"color": uint8 (H, W, 3), "height": float32 (H, W) metres}`` (docs/observation.md)."""


@runtime_checkable
class Env(Protocol):
    """A goal-conditioned pick-and-place world.

    ``reset(seed=s)`` returns the first observation and an info dict holding ``goal`` (an observation of
    the finished structure) and ``progress`` (fraction of blocks placed). ``step(action)`` executes a
    ``(2, 4)`` pick-and-place action and returns ``(obs, reward, terminated, truncated, info)`` with
    ``info`` holding ``success``, ``progress``, ``steps`` and ``primitive`` (how the motion ended).
    """

    task: Task

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Observation, dict]: ...

    def step(self, action: np.ndarray) -> tuple[Observation, float, bool, bool, dict[str, Any]]: ...


class EnvFactory(Protocol):
    """Makes (or reuses) this process's environment for a task; must pickle, to reach worker processes."""

    def __call__(self, task: Task) -> Env: ...
