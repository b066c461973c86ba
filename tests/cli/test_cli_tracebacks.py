"""Former tracebacks (issue 16, case 5): each is one line and exit code 2, before any work is done."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cli_run import run

from tvf.sim.env import ActionError, EpisodeOverError, TvfEnv
from tvf.tasks import load_tasks


def one_line_error(capsys, *args: str) -> str:
    code, out, err = run(capsys, *args)
    assert code == 2, (out, err)
    assert err.startswith("tvf: error: ") and err.strip().count("\n") == 0, err
    return err


@pytest.fixture
def blocker(tmp_path) -> Path:
    """A regular file where a folder is expected."""
    path = tmp_path / "a-file"
    path.write_text("not a folder")
    return path


@pytest.mark.parametrize("flag", ["--batch", "--steps", "--log-every", "--checkpoint-every", "--demos"])
def test_train_count_flags_below_one_fail_before_the_data_is_read(capsys, tmp_path, flag):
    # --data does not exist: an error about the flag proves the check ran before any data was read
    err = one_line_error(capsys, "train", "gctn", "--data", str(tmp_path / "no-data"), "--out",
                         str(tmp_path / "run"), "--preset", "smoke", flag, "0")  # fmt: skip
    assert f"{flag} must be at least 1" in err
    assert not (tmp_path / "run").exists()


def test_train_negative_learning_rate(capsys, tmp_path):
    err = one_line_error(capsys, "train", "vf", "--data", str(tmp_path), "--out", str(tmp_path / "run"),
                         "--lr", "-1")  # fmt: skip
    assert "--lr must be a positive number" in err


def test_train_out_below_a_regular_file(capsys, tmp_path, blocker):
    err = one_line_error(capsys, "train", "gctn", "--data", str(tmp_path / "no-data"),
                         "--out", str(blocker / "run"))  # fmt: skip
    assert f"{blocker} is a file, not a folder" in err and "--out" in err
    assert blocker.read_text() == "not a folder"


def test_experiment_out_below_a_regular_file(capsys, blocker):
    err = one_line_error(capsys, "experiment", "--preset", "smoke", "--out", str(blocker / "exp"))
    assert f"{blocker} is a file, not a folder" in err


def test_experiment_bad_recipe_flag_fails_before_any_stage(capsys, tmp_path):
    err = one_line_error(capsys, "experiment", "--preset", "smoke", "--gctn-batch", "0",
                         "--out", str(tmp_path / "exp"))  # fmt: skip
    assert "gctn training: --batch must be at least 1" in err and "--gctn-" in err
    assert not (tmp_path / "exp").exists()


@pytest.fixture
def no_episodes(monkeypatch):
    """Fail the test if any episode job is started."""
    import tvf.parallel

    def refuse(*args, **kwargs):
        raise AssertionError("an episode ran before the --json check")

    monkeypatch.setattr(tvf.parallel, "run_jobs", refuse)


def test_oracle_json_into_a_folder_fails_before_any_episode(capsys, tmp_path, no_episodes):
    err = one_line_error(
        capsys, "oracle", "--tasks", "stack-stair", "--episodes", "1", "--json", str(tmp_path)
    )
    assert "it is a folder; give --json a file name" in err


def test_oracle_json_below_a_regular_file_fails_before_any_episode(capsys, blocker, no_episodes):
    err = one_line_error(capsys, "oracle", "--tasks", "stack-stair", "--json", str(blocker / "o.json"))
    assert f"{blocker} is a file, not a folder; choose another --json" in err


@pytest.mark.skipif(not Path("/proc/self").exists(), reason="needs /proc (Linux) as an unwritable place")
def test_oracle_json_into_an_unwritable_place_fails_before_any_episode(capsys, no_episodes):
    err = one_line_error(capsys, "oracle", "--tasks", "stack-stair", "--json", "/proc/tvf-test/o.json")
    assert "cannot write to output directory /proc/tvf-test" in err and "--json" in err


# ------------------------------------------------------------------ the environment's step
@pytest.fixture(scope="module")
def one_block_env(tmp_path_factory):
    """An environment of a one-block task: its oracle finishes the episode in one step."""
    path = tmp_path_factory.mktemp("tasks") / "one.yaml"
    path.write_text("tasks:\n  one-block:\n    split: unseen\n    base: stand_1\n    targets: [[0, 0, 0]]\n")
    env = TvfEnv(load_tasks(path).get("one-block"))
    yield env
    env.close()


def test_a_non_numeric_action_is_an_action_error(one_block_env):
    one_block_env.reset(seed=0)
    for action in ("pick it up", [["a", "b", "c", "d"]] * 2, {"pick": 1}):
        with pytest.raises(ActionError, match=r"\(2, 4\) array of numbers"):
            one_block_env.step(action)
    assert one_block_env.steps == 0  # nothing was executed


def test_step_after_terminated_is_refused_until_reset(one_block_env):
    one_block_env.reset(seed=0)
    _, _, terminated, _, info = one_block_env.step(one_block_env.oracle_action())
    assert terminated and info["success"]
    with pytest.raises(EpisodeOverError, match=r"has terminated .* call reset\(\) before step\(\)"):
        one_block_env.step(np.array([[0.5, 0.0, 0.02, 0.0], [0.5, 0.1, 0.02, 0.0]]))
    assert one_block_env.steps == 1
    one_block_env.reset(seed=2)  # a reset starts a new episode
    assert not one_block_env.terminated and one_block_env.steps == 0


def test_the_command_line_parser_imports_neither_torch_nor_pybullet():
    """`tvf --help` stays fast: the parser is built from torch-free config classes (tvf.train.config)."""
    import subprocess
    import sys

    code = "import sys, tvf.cli; assert not {'torch', 'pybullet'} & set(sys.modules), sorted(sys.modules)"
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize(("split", "near"), [("test", "1"), ("train", "-1")])
def test_demos_near_misses_need_the_train_split_and_a_count(capsys, tmp_path, split, near):
    out = str(tmp_path / "d")
    err = one_line_error(capsys, "demos", "--split", split, "--near-misses", near, "--out", out)
    assert "--near-misses" in err and "--split train" in err
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize(
    ("flags", "says"),
    [(["--moves", "gctn"], "only a searching method"), (["--moves", "nope"], "nope"),
     (["--moves", "tvf-large", "--near-misses", "1"], "drop --near-misses")],
)  # fmt: skip
def test_demos_moves_need_a_searching_method_alone(capsys, tmp_path, flags, says):
    err = one_line_error(capsys, "demos", *flags, "--out", str(tmp_path / "d"))
    assert says in err
    assert not (tmp_path / "d").exists()
