"""The one episode loop: a policy acts in an environment from a seed until success or a step budget.

It serves the oracle sweep, closed-loop evaluation, recorded episodes and the quick start. The world
comes from an environment factory (:class:`tvf.envs.EnvFactory`; the simulator by default), so any
world that implements :class:`tvf.envs.Env` runs through the same loop.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np

from tvf.envs import Env, EnvFactory, Observation
from tvf.errors import TvfError
from tvf.policies import Policy, PolicySpec, policy_for
from tvf.sim.factory import SimEnvFactory
from tvf.tasks import Task


@dataclass
class EpisodeResult:
    task: str
    seed: int
    success: bool
    progress: float
    steps: int
    actions: list[list[list[float]]] = field(default_factory=list)
    primitives: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)


def run_episode(
    env: Env, seed: int, policy: Policy, max_steps: int, stuck: str = "no_action",
    on_step: Callable[[Observation, Observation, Policy], None] | None = None,
) -> EpisodeResult:  # fmt: skip
    """Reset ``env`` to ``seed`` and step ``policy.act(obs, goal)`` until success or ``max_steps``.

    ``on_step(obs, goal, policy)`` sees every observation the policy acted on, right after it acted, and
    finally ``on_step(last_obs, goal, None)``; an action of None ends the episode as ``stuck``.
    """
    obs, info = env.reset(seed=seed)
    goal = info["goal"]
    policy.reset()
    result = EpisodeResult(env.task.name, seed, False, info["progress"], 0)
    for _ in range(max_steps):
        action = policy.act(obs, goal)
        if on_step is not None:
            on_step(obs, goal, policy)
        if action is None:
            result.primitives.append(stuck)
            break
        obs, _, terminated, _, info = env.step(action)
        result.actions.append(np.asarray(action).tolist())
        result.primitives.append(info["primitive"])
        result.steps, result.success, result.progress = info["steps"], info["success"], info["progress"]
        if terminated:
            break
    if on_step is not None:
        on_step(obs, goal, None)
    return result


def policy_episode(
    task: Task, seed: int, spec: PolicySpec, step_slack: int = 0, envs: EnvFactory | None = None
) -> EpisodeResult:  # fmt: skip
    """One closed-loop episode of ``spec`` on ``task`` from ``seed`` (horizon: one step per block + slack)."""
    env = (envs or SimEnvFactory())(task)
    stuck = "oracle_stuck" if spec.method == "oracle" else "no_action"
    return run_episode(env, seed, policy_for(spec, env), task.horizon + step_slack, stuck)


def env_factory(spec: str = "sim") -> EnvFactory:
    """The factory named by ``--env``: ``sim`` (the simulator) or ``package.module:Name``, a picklable
    factory (a class is instantiated without arguments) that maps a task to an :class:`~tvf.envs.Env`."""
    if spec == "sim":
        return SimEnvFactory()
    module, _, name = spec.partition(":")
    try:
        found = getattr(importlib.import_module(module), name) if module and name else None
    except (ImportError, AttributeError) as exc:
        found, why = None, f" ({type(exc).__name__}: {exc})"
    else:
        why = ""
    if found is None:
        raise TvfError(f"cannot load environment factory {spec!r}{why}; pass --env sim or --env MODULE:NAME")
    return found() if isinstance(found, type) else found
