"""`tvf eval --envs-per-worker N`: N simulators per process in lock-step give one-at-a-time episodes."""

import json
from dataclasses import dataclass

import pytest
from cli_run import run

from tvf.errors import TvfError
from tvf.evaluate.closed_loop import evaluate
from tvf.evaluate.runner import batch_envs
from tvf.policies import PolicySpec
from tvf.sim.factory import SimEnvFactory, sim_env
from tvf.tasks import Task, get_task

TASK, SEED_START = "stack-tower", 1
TASKS = ["stack-tower", "stack-square"]  # budgets 3 and 4: a group of 3 loses its towers before the square


def _lines(out) -> list[str]:
    return (out / "episodes.jsonl").read_text().splitlines()


# Both (35 s and 2 min on 2 busy cores) run with `make test-all`; the lock-step loop is checked in the
# default run by the oracle's resume below, and batched decisions against single ones in
# tests/planning/test_batched_search.py and tests/policies/test_batched_policies.py
@pytest.mark.slow
@pytest.mark.parametrize("method", ["gctn", "tvf-small"])
def test_envs_per_worker_3_writes_the_episodes_of_one_env_at_a_time(tmp_path, method):
    spec = PolicySpec(method, device="cpu")  # the shipped lite weights
    one = evaluate(spec, TASKS, 2, SEED_START, 1, tmp_path / "one")
    three = evaluate(spec, TASKS, 2, SEED_START, 1, tmp_path / "three", envs_per_worker=3)
    assert _lines(tmp_path / "three") == _lines(tmp_path / "one")  # every field, in seed order
    assert three == one
    records = [json.loads(line) for line in _lines(tmp_path / "one")]
    assert [(r["task"], r["seed"]) for r in records] == [(t, s) for t in TASKS for s in (1, 3)]
    assert len({r["steps"] for r in records}) > 1  # episodes left the batch at different steps


def test_a_batched_evaluation_resumes_an_interrupted_log(tmp_path):
    spec, out = PolicySpec("oracle"), tmp_path / "eval"
    evaluate(spec, TASKS, 2, SEED_START, 1, out)
    full = _lines(out)
    (out / "episodes.jsonl").write_text("\n".join(full[:1]) + "\n" + full[1][:10])  # cut mid-line
    evaluate(spec, TASKS, 2, SEED_START, 1, out, envs_per_worker=2)
    assert _lines(out) == full


def test_each_episode_of_a_task_gets_its_own_world():
    tower = get_task("stack-tower")
    worlds = batch_envs(SimEnvFactory(), [tower, tower, get_task("stack-t")])
    assert len({id(w) for w in worlds}) == 3 and worlds[0] is sim_env(tower)


@dataclass(frozen=True)
class SlotlessFactory:
    def __call__(self, task: Task):
        return sim_env(task)


@pytest.mark.parametrize("bad", [0, -2])
def test_bad_envs_per_worker_is_a_one_line_error(tmp_path, bad):
    with pytest.raises(TvfError, match="--envs-per-worker must be a whole number of at least 1") as err:
        evaluate(PolicySpec("oracle"), [TASK], 1, 1, 1, tmp_path, envs_per_worker=bad)
    assert "\n" not in str(err.value)
    with pytest.raises(TvfError, match="takes no slot argument"):
        evaluate(PolicySpec("oracle"), [TASK], 1, 1, 1, tmp_path, envs=SlotlessFactory(), envs_per_worker=2)


def test_the_cli_refuses_a_bad_envs_per_worker(tmp_path, capsys):
    code, _, err = run(capsys, "eval", "--method", "oracle", "--tasks", TASK, "--episodes", "1",
                       "--envs-per-worker", "0", "--out", str(tmp_path / "e"))  # fmt: skip
    assert code == 2 and "--envs-per-worker must be" in err
    assert len(err.strip().splitlines()) == 1
