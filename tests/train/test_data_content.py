"""Training resumes are keyed on the content of the episodes: a changed file is named and refused, or with
--restart trained again from step 0; an unchanged one resumes."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
from test_training import TASKS, config, synthetic_episode

from tvf.data.format import episode_name, write_episode
from tvf.errors import StaleError
from tvf.models.checkpoint import load_checkpoint
from tvf.runs import RunDir, data_changes
from tvf.train.jobs import gctn_job
from tvf.train.trainer import TrainError, train


def _rewrite(root, split: str, task: str, seed: int) -> None:
    """The same task, seed and step count with other content, as a changed simulator's re-generation gives."""
    path = root / split / task / episode_name(seed)
    path.unlink()
    write_episode(path, replace(synthetic_episode(task, seed + 100, split), seed=seed))


def test_the_run_records_each_episodes_content(own_data, tmp_path):
    cfg = config(own_data, tmp_path / "run", steps=2)
    train(cfg, gctn_job(cfg))
    record = json.loads((tmp_path / "run" / "config.json").read_text())["data_content"]
    assert set(record["episodes"]) == {f"train:{t}/{s}" for t in TASKS for s in (0, 2)} | {
        f"val:{t}/1" for t in TASKS
    }
    assert all(len(v) == 16 for v in record["episodes"].values()) and len(record["digest"]) == 16


@pytest.mark.slow  # make test-all
def test_a_changed_episode_is_named_and_refused_and_restart_trains_from_zero(own_data, tmp_path):
    cfg = config(own_data, tmp_path / "run", steps=2)
    train(cfg, gctn_job(cfg))
    resumed = replace(cfg, steps=4, resume=True)
    train(resumed, gctn_job(resumed))  # the same data: resumes to step 4
    assert load_checkpoint(RunDir(cfg.out).last, "gctn").step == 4

    _rewrite(own_data, "train", TASKS[0], 2)
    with pytest.raises(StaleError, match=rf"other data \(1 episode changed content \(train:{TASKS[0]}/2\)\)"):
        train(resumed, gctn_job(resumed))
    assert load_checkpoint(RunDir(cfg.out).last, "gctn").step == 4  # nothing lost by the refusal

    restart = replace(resumed, steps=2, restart=True)
    train(restart, gctn_job(restart))
    run = RunDir(cfg.out)
    assert load_checkpoint(run.last, "gctn").step == 2  # trained again from 0, not resumed past 4
    assert [s for s, _ in run.step_checkpoints()] == [2]
    assert max(r["step"] for r in run.metrics()) == 2
    now = run.read_config()["data_content"]["episodes"][f"train:{TASKS[0]}/2"]
    again = replace(restart, restart=False)
    train(again, gctn_job(again))  # the new content is the record now: a plain resume goes on
    assert run.read_config()["data_content"]["episodes"][f"train:{TASKS[0]}/2"] == now


def test_a_changed_validation_episode_is_named(own_data, tmp_path):
    cfg = config(own_data, tmp_path / "run", steps=2)
    train(cfg, gctn_job(cfg))
    _rewrite(own_data, "test", TASKS[1], 1)
    resumed = replace(cfg, resume=True)
    with pytest.raises(StaleError, match=rf"val:{TASKS[1]}/1"):
        train(resumed, gctn_job(resumed))


@pytest.mark.slow  # make test-all
def test_a_run_from_before_contents_were_recorded_resumes(own_data, tmp_path):
    cfg = config(own_data, tmp_path / "run", steps=2)
    train(cfg, gctn_job(cfg))
    run = RunDir(cfg.out)
    old = run.read_config()
    del old["data_content"]
    run.config_path.write_text(json.dumps(old))
    _rewrite(own_data, "train", TASKS[0], 0)
    resumed = replace(cfg, steps=4, resume=True)
    train(resumed, gctn_job(resumed))  # trusted on its episode list, as before this check existed
    assert load_checkpoint(run.last, "gctn").step == 4


def test_restart_needs_resume(own_data, tmp_path):
    cfg = config(own_data, tmp_path / "run", restart=True)
    with pytest.raises(TrainError, match="--restart goes with --resume"):
        train(cfg, gctn_job(cfg))


def test_data_changes_names_changed_added_and_removed_episodes():
    before = {"digest": "a", "episodes": {"train:x/1": "1", "train:x/3": "3", "val:y/1": "v"}}
    now = {"digest": "b", "episodes": {"train:x/1": "9", "train:x/5": "5", "val:y/1": "v"}}
    assert data_changes(before, now) == (
        "1 episode changed content (train:x/1), 1 episode added (train:x/5), 1 episode removed (train:x/3)"
    )
    assert data_changes(before, {**before}) == ""
    assert data_changes(None, now) == ""
    many = {"digest": "c", "episodes": {f"train:x/{i}": "0" for i in range(5)}}
    assert data_changes({"digest": "d", "episodes": {}}, many).startswith("5 episodes added (train:x/0, ")
    assert data_changes({"digest": "d", "episodes": {}}, many).endswith(", …)")
