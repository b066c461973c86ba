"""The simulator through Gymnasium: registered ids, spec, render, the goal in the observation, check_env."""

import subprocess
import sys
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from tvf.envs import BUILTIN_IDS, ENTRY_POINT, env_id, env_name, register_envs
from tvf.errors import TvfError
from tvf.sim.env import TvfEnv
from tvf.tasks import BUILTIN, load_tasks

MY_TASKS = "tasks:\n  my-tower:\n    split: unseen\n    base: stand_1\n    targets: [[0, 0, 0], [0, 0, 1]]\n"


@pytest.fixture
def registry():
    """Leave Gymnasium's registry as the import made it: drop file ids, restore the built-in ones."""
    yield
    for eid in [e for e in gymnasium.registry if e.startswith("tvf/") and e not in BUILTIN_IDS]:
        del gymnasium.registry[eid]
    for eid in BUILTIN_IDS:
        del gymnasium.registry[eid]
    assert tuple(register_envs()) == BUILTIN_IDS


def test_every_builtin_task_has_an_id_by_the_one_rule():
    assert len(BUILTIN_IDS) == len(BUILTIN.tasks) == 14
    assert tuple(env_id(name) for name in BUILTIN.names()) == BUILTIN_IDS
    assert env_id("stack-stair") == "tvf/StackStair-v0" and env_id("put-t") == "tvf/PutT-v0"
    assert env_name("stack-big-stair") == "StackBigStair" and env_name("my_task 2") == "MyTask2"
    for name, eid in zip(BUILTIN.names(), BUILTIN_IDS, strict=True):
        spec = gymnasium.spec(eid)
        assert spec.entry_point == ENTRY_POINT and spec.kwargs == {"task": name}
    with pytest.raises(TvfError, match="no letters or digits"):
        env_name("--")


def test_registration_imports_no_simulator_and_import_tvf_stays_light():
    code = (
        "import sys, tvf; assert 'gymnasium' not in sys.modules and 'numpy' not in sys.modules\n"
        "import gymnasium, tvf.envs; assert 'tvf/StackStair-v0' in gymnasium.registry\n"
        "assert 'pybullet' not in sys.modules and 'tvf.sim.env' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def _check(eid: str) -> None:
    env = gymnasium.make(eid, render_mode="rgb_array")
    try:
        assert env.spec.id == eid and env.metadata["render_fps"] == 1
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a checker warning fails the test
            check_env(env.unwrapped)
        obs, info = env.reset(seed=3)
        assert env.observation_space.contains(obs)
        for key in ("color", "height"):
            np.testing.assert_array_equal(obs["desired_goal"][key], info["goal"][key])
        assert not np.array_equal(obs["height"], obs["desired_goal"]["height"])  # the goal is not the scene
        frame = env.render()
        assert frame.dtype == np.uint8 and frame.shape == (160, 160, 3)
        np.testing.assert_array_equal(frame, obs["color"])
    finally:
        env.close()


def test_check_env_passes_on_a_registered_id():
    _check("tvf/StackTower-v0")


@pytest.mark.slow
@pytest.mark.parametrize("eid", BUILTIN_IDS)
def test_check_env_passes_on_every_registered_id(eid):
    _check(eid)


def test_a_task_file_registers_its_tasks(tmp_path, registry):
    path = tmp_path / "mine.yaml"
    path.write_text(MY_TASKS)
    assert register_envs(path) == ["tvf/MyTower-v0"]
    assert gymnasium.spec("tvf/MyTower-v0").kwargs == {"task": "my-tower", "task_file": str(path.resolve())}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert register_envs(path) == ["tvf/MyTower-v0"]  # again: nothing changes, no override warning
        env = gymnasium.make("tvf/MyTower-v0")
    try:
        assert env.unwrapped.task == load_tasks(path).get("my-tower")
        obs, _ = env.reset(seed=1)
        assert env.observation_space.contains(obs)
    finally:
        env.close()


def test_a_task_file_may_replace_a_builtin_id_but_not_steal_one(tmp_path, registry):
    replace = tmp_path / "replace.yaml"
    replace.write_text(MY_TASKS.replace("my-tower", "stack-tower"))
    assert register_envs(replace) == ["tvf/StackTower-v0"]
    assert gymnasium.spec("tvf/StackTower-v0").kwargs["task_file"] == str(replace.resolve())
    steal = tmp_path / "steal.yaml"
    steal.write_text(MY_TASKS.replace("my-tower", "stack_tower"))
    with pytest.raises(TvfError, match="'stack_tower' maps to Gymnasium id tvf/StackTower-v0.*'stack-tower'"):
        register_envs(steal)
    twins = tmp_path / "twins.yaml"
    twins.write_text(MY_TASKS + MY_TASKS.replace("my-tower", "my_tower").replace("tasks:\n", ""))
    with pytest.raises(TvfError, match="'my_tower' maps to .*tvf/MyTower-v0.*'my-tower'"):
        register_envs(twins)
    assert "tvf/MyTower-v0" not in gymnasium.registry  # nothing half-registered


def test_unsupported_render_mode_and_task_value_with_file_are_one_line_errors(tmp_path):
    with pytest.raises(TvfError, match="render_mode 'human' is not supported"):
        TvfEnv("stack-tower", render_mode="human")
    with pytest.raises(TvfError, match="task name together with task_file"):
        TvfEnv(BUILTIN.get("stack-tower"), task_file=tmp_path / "x.yaml")
