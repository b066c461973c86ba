"""The one episode loop: a policy acts in an environment from a seed until success or a step budget.

It serves the oracle sweep, closed-loop evaluation, recorded episodes and the quick start. The world
comes from an environment factory (:class:`tvf.envs.EnvFactory`; the simulator by default), so any
world that implements :class:`tvf.envs.Env` runs through the same loop. :func:`run_episodes` is the
same loop over several environments in lock-step (`tvf eval --envs-per-worker`): every step asks the
policy for all unfinished environments' actions at once, so their planner work shares model calls.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from tvf.envs import Env, EnvFactory, Observation
from tvf.errors import TvfError
from tvf.policies import Policy, PolicySpec, act_all, policy_for
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
    misses: list[dict] = field(default_factory=list)
    """How each target unfilled at the end is missed (:func:`tvf.sim.success.target_misses`), where the
    world reports it (``info["misses"]``; the simulator does)."""

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
    result = EpisodeResult(env.task.name, seed, False, info["progress"], 0, misses=info.get("misses", []))
    for _ in range(max_steps):
        action = policy.act(obs, goal)
        if on_step is not None:
            on_step(obs, goal, policy)
        if action is None:
            result.primitives.append(stuck)
            break
        obs, _, terminated, _, info = env.step(action)
        _record_step(result, action, info)
        if terminated:
            break
    if on_step is not None:
        on_step(obs, goal, None)
    return result


def _record_step(result: EpisodeResult, action: np.ndarray, info: dict) -> None:
    result.actions.append(np.asarray(action).tolist())
    result.primitives.append(info["primitive"])
    result.steps, result.success, result.progress = info["steps"], info["success"], info["progress"]
    result.misses = info.get("misses", [])


def run_episodes(
    envs: Sequence[Env], seeds: Sequence[int], policies: Sequence[Policy], max_steps: int | Sequence[int],
    stuck: str = "no_action",
) -> list[EpisodeResult]:  # fmt: skip
    """:func:`run_episode` of ``policies[i]`` in ``envs[i]`` from ``seeds[i]`` with a budget of
    ``max_steps`` (one for all, or one each), all environments in lock-step: each step asks
    :func:`~tvf.policies.act_all` for every unfinished one's action at once (one batched decision when
    they share a policy), then steps each. An environment whose episode ends (success, no action, its
    step budget) leaves the batch. Each result is the one :func:`run_episode` gives.
    """
    if len({id(env) for env in envs}) < len(envs):
        raise TvfError("run_episodes needs a separate environment for every episode of the batch")
    budgets = [max_steps] * len(envs) if isinstance(max_steps, int) else list(max_steps)
    observations, goals, results = [], [], []
    for env, seed, policy in zip(envs, seeds, policies, strict=True):
        obs, info = env.reset(seed=seed)
        policy.reset()
        observations.append(obs)
        goals.append(info["goal"])
        results.append(EpisodeResult(env.task.name, seed, False, info["progress"], 0,
                                     misses=info.get("misses", [])))  # fmt: skip
    active, taken = [i for i, budget in enumerate(budgets) if budget > 0], 0
    while active:
        actions = act_all([policies[i] for i in active], [observations[i] for i in active],
                          [goals[i] for i in active])  # fmt: skip
        taken += 1
        still = []
        for i, action in zip(active, actions, strict=True):
            if action is None:
                results[i].primitives.append(stuck)
                continue
            observations[i], _, terminated, _, info = envs[i].step(action)
            _record_step(results[i], action, info)
            if not terminated and taken < budgets[i]:
                still.append(i)
        active = still
    return results


def policy_episode(
    task: Task, seed: int, spec: PolicySpec, step_slack: int = 0, envs: EnvFactory | None = None
) -> EpisodeResult:  # fmt: skip
    """One closed-loop episode of ``spec`` on ``task`` from ``seed`` (horizon: one step per block + slack)."""
    env = (envs or SimEnvFactory())(task)
    stuck = "oracle_stuck" if spec.method == "oracle" else "no_action"
    return run_episode(env, seed, policy_for(spec, env), task.horizon + step_slack, stuck)


def policy_episodes(
    jobs: Sequence[tuple[Task, int]], spec: PolicySpec, step_slack: int = 0, envs: EnvFactory | None = None
) -> list[EpisodeResult]:  # fmt: skip
    """:func:`policy_episode` of every ``(task, seed)`` job, their environments stepped in lock-step
    (:func:`run_episodes`, each episode to its own step budget): one process's share of
    `tvf eval --envs-per-worker N`."""
    worlds = batch_envs(envs or SimEnvFactory(), [task for task, _ in jobs])
    stuck = "oracle_stuck" if spec.method == "oracle" else "no_action"
    return run_episodes(worlds, [seed for _, seed in jobs], [policy_for(spec, env) for env in worlds],
                        [task.horizon + step_slack for task, _ in jobs], stuck)  # fmt: skip


def check_envs_per_worker(n: int, envs: EnvFactory | None = None) -> int:
    """``n`` if it is a usable `--envs-per-worker`: at least 1, and above 1 only with a factory that makes
    a separate world per ``slot`` (the simulator does); otherwise a one-line error naming the fix."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise TvfError(f"--envs-per-worker must be a whole number of at least 1 (environments one process "
                       f"steps together), got {n!r}")  # fmt: skip
    if n > 1 and envs is not None and not _takes_slot(envs):
        raise TvfError(
            f"--envs-per-worker {n} steps several worlds of a task in one process, but the environment "
            f"factory {type(envs).__name__} takes no slot argument; give its __call__ a `slot: int = 0` "
            "parameter (a separate world per slot) or use --envs-per-worker 1"
        )
    return n


def _takes_slot(envs: EnvFactory) -> bool:
    try:
        return "slot" in inspect.signature(envs).parameters
    except (TypeError, ValueError):  # a callable without a signature
        return False


def batch_envs(envs: EnvFactory, tasks: Sequence[Task]) -> list[Env]:
    """One environment per task of a batch: the k-th episode of a task gets ``envs(task, slot=k)``.

    A factory whose call takes no ``slot`` serves batches with one episode per task only (it may hand
    the same world back for a task, as the simulator's per-process cache does without slots)."""
    takes_slot = _takes_slot(envs)
    seen: dict[Task, int] = {}
    out = []
    for task in tasks:
        slot = seen[task] = seen.get(task, -1) + 1
        if slot and not takes_slot:
            raise TvfError(
                f"--envs-per-worker above 1 steps several {task.name} worlds in one process, but the "
                f"environment factory {type(envs).__name__} takes no slot argument; give its __call__ a "
                "`slot: int = 0` parameter (a separate world per slot) or use --envs-per-worker 1"
            )
        out.append(envs(task, slot=slot) if takes_slot else envs(task))
    return out


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
