"""Run many (task, seed) episodes, in parallel processes, with a progress bar.

PyBullet has one client per process, so parallelism is over processes (spawn), each keeping one
environment per task. Results come back in job order whatever the number of workers.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from tqdm import tqdm

_ENVS: dict = {}


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


def init_worker(task_file: str | None = None, threads: int = 1) -> None:
    """Per-process set-up: register a user's task file; one torch thread per process."""
    os.environ.setdefault("OMP_NUM_THREADS", str(threads))
    if task_file:
        from tvf.tasks import load_task_file, register_tasks

        register_tasks(load_task_file(task_file))
    try:
        import torch

        torch.set_num_threads(threads)
    except ImportError:  # pragma: no cover - torch is a dependency
        pass


def cached_env(task: str, gui: bool = False):
    """This process's environment for ``task`` (created on first use; ``gui`` opens a PyBullet window)."""
    from tvf.sim.env import TvfEnv

    if task not in _ENVS:
        _ENVS[task] = TvfEnv(task, gui=gui)
    return _ENVS[task]


def run_episode(
    env, seed: int, act: Callable, max_steps: int, stuck: str = "no_action", on_obs: Callable | None = None
) -> EpisodeResult:
    """Reset ``env`` to ``seed`` and step ``act(obs, goal) -> action | None`` until success or ``max_steps``.

    ``on_obs(obs, goal)`` sees every observation (the first one included); an action of None ends the episode
    and is recorded as ``stuck``.
    """
    obs, info = env.reset(seed=seed)
    goal = info["goal"]
    result = EpisodeResult(env.task.name, seed, False, info["progress"], 0)
    if on_obs is not None:
        on_obs(obs, goal)
    for _ in range(max_steps):
        action = act(obs, goal)
        if action is None:
            result.primitives.append(stuck)
            break
        obs, _, terminated, _, info = env.step(action)
        if on_obs is not None:
            on_obs(obs, goal)
        result.actions.append(np.asarray(action).tolist())
        result.primitives.append(info["primitive"])
        result.steps, result.success, result.progress = info["steps"], info["success"], info["progress"]
        if terminated:
            break
    return result


def oracle_episode(task: str, seed: int, step_slack: int = 0, gui: bool = False) -> EpisodeResult:
    """Run the scripted expert on ``task`` from ``seed`` until success or the step horizon."""
    env = cached_env(task, gui)
    return run_episode(env, seed, lambda obs, goal: env.oracle_action(), env.task.horizon + step_slack,
                       stuck="oracle_stuck")  # fmt: skip


def run_jobs(
    fn: Callable, jobs: Sequence[tuple], workers: int = 1, desc: str = "episodes",
    task_file: str | Path | None = None, progress: bool = True,
) -> Iterator:  # fmt: skip
    """Yield ``fn(*job)`` for each job, in order, using ``workers`` processes (1 = this process)."""
    bar = tqdm(total=len(jobs), desc=desc, unit="ep", disable=not progress, dynamic_ncols=True)
    tf = str(task_file) if task_file else None
    try:
        if workers <= 1:
            init_worker(tf, threads=max(1, os.cpu_count() or 1))
            for job in jobs:
                yield fn(*job)
                bar.update()
            return
        ctx = get_context("spawn")
        with ProcessPoolExecutor(workers, mp_context=ctx, initializer=init_worker, initargs=(tf, 1)) as pool:
            futures = [pool.submit(fn, *job) for job in jobs]
            for fut in futures:
                yield fut.result()
                bar.update()
    finally:
        bar.close()
