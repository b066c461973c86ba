"""The environment seam: what the episode loop needs from a world, simulated or real, and the Gymnasium ids.

The simulator (:class:`tvf.sim.env.TvfEnv`, made by :class:`tvf.sim.factory.SimEnvFactory`) is the first
implementation; a real robot, a camera-noise wrapper or a vector of environments implements the same
two calls and plugs into :func:`tvf.evaluate.runner.run_episode` and `tvf eval` without touching the loop.

Importing this module registers ``tvf/<Task>-v0`` with Gymnasium for every built-in task (the name rule
is :func:`env_name`); :func:`register_envs` registers the tasks of a task file. Registration stores an
entry-point string only: the simulator is imported when ``gymnasium.make`` builds an environment.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import gymnasium
import numpy as np

from tvf.errors import TvfError
from tvf.tasks import BUILTIN, Task, load_task_file

Observation = dict[str, np.ndarray]
"""``{"color": uint8 (H, W, 3), "height": float32 (H, W) metres}`` (docs/observation.md); the simulator
adds ``"desired_goal"``, the goal image in the same form (docs/gymnasium.md)."""

NAMESPACE = "tvf"
ENV_VERSION = 0
ENTRY_POINT = "tvf.sim.env:TvfEnv"
"""What ``gymnasium.make`` imports and calls with the registered kwargs (``task``, ``task_file``)."""


@runtime_checkable
class Env(Protocol):
    """A goal-conditioned pick-and-place world.

    ``reset(seed=s)`` returns the first observation and an info dict holding ``goal`` (an observation of
    the finished structure) and ``progress`` (fraction of blocks placed). ``step(action)`` executes a
    ``(2, 4)`` pick-and-place action and returns ``(obs, reward, terminated, truncated, info)`` with
    ``info`` holding ``success``, ``progress``, ``steps`` and ``primitive`` (how the motion ended); a world
    that can also says in ``info["misses"]`` how each unfilled target is missed
    (:func:`tvf.sim.success.target_misses`), which evaluations record.
    """

    task: Task

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Observation, dict]: ...

    def step(self, action: np.ndarray) -> tuple[Observation, float, bool, bool, dict[str, Any]]: ...


class EnvFactory(Protocol):
    """Makes (or reuses) this process's environment for a task; must pickle, to reach worker processes.

    A factory that also takes ``slot: int = 0`` (a separate world per slot, as
    :class:`tvf.sim.factory.SimEnvFactory`) serves `tvf eval --envs-per-worker N`, which steps several
    worlds of one task side by side."""

    def __call__(self, task: Task) -> Env: ...


def env_name(task_name: str) -> str:
    """The CamelCase name of a task: split at every run of characters that are not letters or digits, and
    capitalise each part's first letter (``stack-big-stair`` -> ``StackBigStair``, ``put-t`` -> ``PutT``)."""
    parts = [p for p in re.split(r"[^A-Za-z0-9]+", task_name) if p]
    if not parts:
        raise TvfError(f"task name {task_name!r} has no letters or digits for a Gymnasium id; rename it")
    return "".join(p[0].upper() + p[1:] for p in parts)


def env_id(task_name: str) -> str:
    """The Gymnasium id of a task: ``tvf/<CamelCase>-v0`` (``stack-stair`` -> ``tvf/StackStair-v0``)."""
    return f"{NAMESPACE}/{env_name(task_name)}-v{ENV_VERSION}"


def _check_ids(names: list[str], source: str) -> None:
    """Each task its own id: two names of one table, or a new name on a registered id, are errors."""
    seen: dict[str, str] = {}
    for name in names:
        eid = env_id(name)
        other = seen.setdefault(eid, name)
        registered = gymnasium.registry[eid].kwargs.get("task") if eid in gymnasium.registry else name
        owner = other if other != name else registered
        if owner != name:
            raise TvfError(
                f"{source}: task {name!r} maps to Gymnasium id {eid}, which belongs to task {owner!r}; "
                "rename one of them"
            )


def _register(task_name: str, kwargs: dict[str, str]) -> str:
    """Register one id; again only when its kwargs changed (a task file replacing a built-in task)."""
    eid = env_id(task_name)
    old = gymnasium.registry.get(eid)
    if old is not None and old.kwargs == kwargs:
        return eid
    if old is not None:
        del gymnasium.registry[eid]  # replaced on purpose: spare the user Gymnasium's override warning
    gymnasium.register(eid, entry_point=ENTRY_POINT, kwargs=kwargs)
    return eid


def register_envs(task_file: str | Path | None = None) -> list[str]:
    """Register ``tvf/<Task>-v0`` for the built-in tasks (no argument; importing this module does it) or for
    every task a task file defines (docs/tasks.md), and return the ids in table order.

    A file task with a built-in name replaces that id, as ``tvf.tasks.load_tasks`` replaces the task.
    """
    if task_file is None:
        names, extra = BUILTIN.names(), {}
    else:
        path = Path(task_file).resolve()
        names, extra = list(load_task_file(path)), {"task_file": str(path)}
    _check_ids(names, str(task_file or "tasks.yaml"))
    return [_register(name, {"task": name, **extra}) for name in names]


BUILTIN_IDS = tuple(register_envs())
"""The ids of the built-in tasks, registered when this module is imported."""
