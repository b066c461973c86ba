"""The simulator as an environment factory (the default of every command that runs episodes)."""

from __future__ import annotations

from dataclasses import dataclass

from tvf.sim.env import TvfEnv
from tvf.tasks import Task

_ENVS: dict[tuple[Task, bool, int], TvfEnv] = {}


@dataclass(frozen=True)
class SimEnvFactory:
    """One PyBullet environment per task, slot and process, created on first use (a picklable value).

    ``slot`` tells apart the environments of one task that a process steps side by side
    (`tvf eval --envs-per-worker`); each slot is a world of its own.
    """

    gui: bool = False
    """Open a PyBullet window (needs a display; one process)."""

    def __call__(self, task: Task, slot: int = 0) -> TvfEnv:
        key = (task, self.gui, slot)
        if key not in _ENVS:
            _ENVS[key] = TvfEnv(task, gui=self.gui)
        return _ENVS[key]


def sim_env(task: Task) -> TvfEnv:
    """This process's headless simulator for ``task``."""
    return SimEnvFactory()(task)
