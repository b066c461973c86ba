"""Recorded episodes: every observation a policy acted on, with the plan it made there (for GIFs)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from tvf.envs import Env, Observation
from tvf.evaluate.runner import EpisodeResult, run_episode
from tvf.planning.search import Plan
from tvf.policies import Policy


@dataclass
class RecordedStep:
    """One observation of an episode and what happened there.

    ``plan`` is the TVF search made on it (None: no search, or the end); ``action`` the ``(2, 4)`` action
    executed from it (None on the last observation and when the policy gave up); ``progress`` the fraction
    of targets filled in this observation and ``primitive`` how the motion from it ended.
    """

    obs: Observation
    goal: Observation
    plan: Plan | None = None
    action: np.ndarray | None = None
    progress: float = 0.0
    primitive: str | None = None


@dataclass(frozen=True)
class RecordedEpisode:
    """What an episode GIF needs besides the steps: the task, the seed, the method and the outcome."""

    task: str
    seed: int
    method: str
    n_targets: int
    horizon: int
    success: bool

    def done(self, progress: float) -> int:
        """Targets filled at ``progress`` (a fraction of ``n_targets``)."""
        return int(round(progress * self.n_targets))


class _InfoTap:
    """An environment that passes every call through and keeps the info dicts, oldest first."""

    def __init__(self, env: Env) -> None:
        self.env = env
        self.task = env.task
        self.infos: list[dict[str, Any]] = []

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Observation, dict]:
        obs, info = self.env.reset(seed=seed, options=options)
        self.infos.append(info)
        return obs, info

    def step(self, action: np.ndarray):
        out = self.env.step(action)
        self.infos.append(out[4])
        return out


def record_episode(
    policy: Policy, env: Env, seed: int, max_steps: int
) -> tuple[EpisodeResult, list[RecordedStep]]:
    """Run one episode and keep every observation (the final one last) with the policy's plan there, the
    action taken from it and the progress it shows.

    A planner keeps its imagined images during the episode only (``keep_images``), for the pictures.
    """
    steps: list[RecordedStep] = []
    keeps = hasattr(policy, "keep_images")
    tap = _InfoTap(env)

    def on_step(obs: Observation, goal: Observation, acted: Policy | None) -> None:
        plan = getattr(acted, "last_plan", None) if acted is not None else None
        steps.append(RecordedStep(obs, goal, plan))

    if keeps:
        policy.keep_images = True
    try:
        result = run_episode(tap, seed, policy, max_steps, on_step=on_step)
    finally:
        if keeps:
            policy.keep_images = False
    for i, step in enumerate(steps):
        # observation i follows i actions: the reset's info, then one info per executed step
        step.progress = float(tap.infos[min(i, len(tap.infos) - 1)]["progress"])
        if i < len(result.actions):
            step.action = np.asarray(result.actions[i], dtype=np.float64)
        if i < len(result.primitives):
            step.primitive = result.primitives[i]  # "no_action" where the policy gave up
    return result, steps
