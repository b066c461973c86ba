"""The simulator as an environment factory (the default of every command that runs episodes)."""

from __future__ import annotations

from dataclasses import dataclass

from tvf.sim.env import TvfEnv
from tvf.tasks import Task

_ENVS: dict[tuple[Task, bool], TvfEnv] = {}


@dataclass(frozen=True)
class SimEnvFactory:
    """One PyBullet environment per task and process, created on first use (a picklable value)."""

    gui: bool = False
    """Open a PyBullet window (needs a display; one process)."""

    def __call__(self, task: Task) -> TvfEnv:
        key = (task, self.gui)
        if key not in _ENVS:
            _ENVS[key] = TvfEnv(task, gui=self.gui)
        return _ENVS[key]


def sim_env(task: Task) -> TvfEnv:
    """This process's headless simulator for ``task``."""
    return SimEnvFactory()(task)
