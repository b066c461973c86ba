"""Recorded episodes: every observation a policy acted on, with the plan it made there (for GIFs)."""

from __future__ import annotations

from dataclasses import dataclass

from tvf.envs import Env, Observation
from tvf.evaluate.runner import EpisodeResult, run_episode
from tvf.planning.search import Plan
from tvf.policies import Policy


@dataclass
class RecordedStep:
    """One observation of an episode; ``plan`` is the TVF search made on it (None: no search, or the end)."""

    obs: Observation
    goal: Observation
    plan: Plan | None = None


def record_episode(
    policy: Policy, env: Env, seed: int, max_steps: int
) -> tuple[EpisodeResult, list[RecordedStep]]:
    """Run one episode and keep every observation (the final one last) with the policy's plan there.

    A planner keeps its imagined images during the episode only (``keep_images``), for the pictures.
    """
    steps: list[RecordedStep] = []
    keeps = hasattr(policy, "keep_images")

    def on_step(obs: Observation, goal: Observation, acted: Policy | None) -> None:
        plan = getattr(acted, "last_plan", None) if acted is not None else None
        steps.append(RecordedStep(obs, goal, plan))

    if keeps:
        policy.keep_images = True
    try:
        result = run_episode(env, seed, policy, max_steps, on_step=on_step)
    finally:
        if keeps:
            policy.keep_images = False
    return result, steps
