"""The environment seam: any factory of `Env`s runs through the episode loop and `evaluate`, and a task
from a user's file reaches worker processes as a value (no module state)."""

import json
from dataclasses import dataclass

import numpy as np
import pytest
from cli_run import run

from tvf.envs import Env
from tvf.evaluate.closed_loop import evaluate
from tvf.evaluate.runner import run_episode
from tvf.policies import OraclePolicy, PolicySpec
from tvf.sim.factory import SimEnvFactory, sim_env
from tvf.tasks import Task, get_task, load_tasks

SEEN: list[int] = []


class NoisyDepth:
    """A camera-noise wrapper: the simulator with seeded Gaussian noise on every height map."""

    def __init__(self, env, sigma: float = 0.002) -> None:
        self.env, self.task, self.sigma = env, env.task, sigma
        self.rng = np.random.default_rng(0)

    def _noisy(self, obs: dict) -> dict:
        noise = self.rng.normal(0.0, self.sigma, obs["height"].shape).astype(np.float32)
        return {**obs, "height": obs["height"] + noise}

    def reset(self, *, seed=None, options=None):
        SEEN.append(seed)
        self.rng = np.random.default_rng(seed)
        obs, info = self.env.reset(seed=seed)
        return self._noisy(obs), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._noisy(obs), reward, terminated, truncated, info

    def oracle_action(self):
        return self.env.oracle_action()


@dataclass(frozen=True)
class NoisyFactory:
    sigma: float = 0.002

    def __call__(self, task: Task) -> Env:
        return NoisyDepth(sim_env(task), self.sigma)


def test_the_simulator_implements_the_env_protocol():
    assert isinstance(sim_env(get_task("stack-stair")), Env)
    assert isinstance(NoisyFactory()(get_task("stack-stair")), Env)


def _records(out) -> list[dict]:
    return sorted(map(json.loads, (out / "episodes.jsonl").read_text().splitlines()), key=lambda r: r["seed"])


@pytest.fixture(scope="module")
def clean_gctn(tmp_path_factory):
    """The shipped GCTN on two stack-stair episodes in the plain simulator, in this process."""
    out = tmp_path_factory.mktemp("clean")
    return out, evaluate(PolicySpec("gctn"), ["stack-stair"], 2, 1, 1, out)


def test_a_wrapped_environment_is_evaluated_through_the_same_loop(tmp_path, clean_gctn):
    SEEN.clear()
    summary = evaluate(PolicySpec("gctn"), ["stack-stair"], 2, 1, 1, tmp_path, envs=NoisyFactory())
    assert SEEN == [1, 3] and summary["average"]["episodes"] == 2
    noisy_actions = [r["actions"] for r in _records(tmp_path)]
    clean_actions = [r["actions"] for r in _records(clean_gctn[0])]
    assert noisy_actions != clean_actions  # the wrapper's images, not the simulator's, reached the policy


@pytest.mark.slow
def test_one_and_two_workers_give_identical_gctn_episodes(tmp_path, clean_gctn):
    """The clean run again in two spawned workers (one torch thread each, where this process may use
    more): the same actions, outcomes and summary. (The default run checks this with the oracle in
    test_a_task_file_task_runs_in_worker_processes.)"""
    summary = evaluate(PolicySpec("gctn"), ["stack-stair"], 2, 1, 2, tmp_path)
    assert summary == clean_gctn[1]
    records = _records(tmp_path)
    assert records == _records(clean_gctn[0]) and len(records) == 2 and all(r["actions"] for r in records)


def test_the_loop_stops_at_the_step_budget_and_sees_every_observation():
    env, seen = sim_env(get_task("stack-stair")), []
    result = run_episode(env, 1, OraclePolicy(env), 2, on_step=lambda o, g, p: seen.append(p is None))
    assert result.steps == 2 and not result.success
    assert seen == [False, False, True]  # two acted-on observations, then the final one


def test_a_task_file_task_runs_in_worker_processes(tmp_path):
    path = tmp_path / "extra.json"
    path.write_text(json.dumps({"tasks": {"my-pair": {"split": "unseen", "base": "stand_2",
                                                       "targets": [[0, 0, 0], [0, 0.05, 0]]}}}))  # fmt: skip
    task = load_tasks(path).get("my-pair")
    summary = evaluate(PolicySpec("oracle"), [task], 2, 1, 2, tmp_path / "eval", envs=SimEnvFactory())
    assert summary["average"]["success"] == 1.0 and [r["task"] for r in summary["tasks"]] == ["my-pair"]
    # worker-count determinism: the same episodes in this process give the same records, action by action
    assert evaluate(PolicySpec("oracle"), [task], 2, 1, 1, tmp_path / "one") == summary
    assert _records(tmp_path / "one") == _records(tmp_path / "eval")


def test_tvf_eval_takes_an_environment_factory_by_name(tmp_path, capsys):
    SEEN.clear()
    code, _, err = run(capsys, "eval", "--method", "gctn", "--tasks", "stack-stair", "--episodes", "1",
                         "--env", "test_env_seam:NoisyFactory", "--out", str(tmp_path))  # fmt: skip
    assert code == 0, err
    assert SEEN == [1000001]  # the test range by default, through the wrapper
    assert json.loads((tmp_path / "eval.json").read_text())["env"].endswith("NoisyFactory")
    code, _, err = run(capsys, "eval", "--env", "nowhere:Robot", "--out", str(tmp_path / "x"))
    assert code == 2 and "cannot load environment factory 'nowhere:Robot'" in err
