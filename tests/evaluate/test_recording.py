"""Recorded episodes: the same episode as the plain loop, plus the action, progress and motion of every
recorded observation (what the labelled GIFs print)."""

from __future__ import annotations

import numpy as np

from tvf.evaluate.recording import RecordedEpisode, record_episode
from tvf.evaluate.runner import run_episode
from tvf.policies import OraclePolicy
from tvf.sim.factory import sim_env
from tvf.tasks import get_task


def test_recording_changes_nothing_and_keeps_actions_and_progress():
    task = get_task("stack-stair")
    plain_env = sim_env(task)
    plain = run_episode(plain_env, 3, OraclePolicy(plain_env), task.horizon, stuck="oracle_stuck")
    env = sim_env(task)
    result, steps = record_episode(OraclePolicy(env), env, 3, task.horizon)
    assert result.to_dict() == plain.to_dict()  # the same episode, action for action
    assert len(steps) == result.steps + 1 and result.success
    for step, action in zip(steps, result.actions, strict=False):
        assert np.array_equal(step.action, np.asarray(action)) and step.primitive == "ok"
    assert steps[-1].action is None and steps[-1].plan is None
    progress = [s.progress for s in steps]
    assert progress[0] == 0.0 and progress[-1] == result.progress == 1.0
    assert progress == sorted(progress)  # the oracle never undoes a target
    episode = RecordedEpisode(task.name, 3, "oracle", task.n_blocks, task.horizon, result.success)
    assert [episode.done(p) for p in progress] == list(range(task.n_blocks + 1))


class GivesUp:
    """The oracle for one step, then no action."""

    name = "gives-up"

    def __init__(self, env) -> None:
        self.oracle, self.calls = OraclePolicy(env), 0

    def reset(self) -> None:
        self.calls = 0

    def act(self, obs, goal):
        self.calls += 1
        return self.oracle.act(obs, goal) if self.calls == 1 else None


def test_a_policy_that_gives_up_is_recorded_as_such():
    task = get_task("stack-stair")
    env = sim_env(task)
    result, steps = record_episode(GivesUp(env), env, 1, task.horizon)
    assert result.steps == 1 and result.primitives == ["ok", "no_action"]
    assert len(steps) == 3  # acted, gave up, the final observation
    assert steps[0].action is not None and steps[1].action is None and steps[1].primitive == "no_action"
    assert steps[1].progress == steps[2].progress == result.progress
