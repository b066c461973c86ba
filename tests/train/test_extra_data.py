"""`tvf train vf --extra-data`: a folder of a method's own moves added to the drawn demonstrations, recorded
in the run's config; refused for the GCTN, as --data, and when it holds demonstrations."""

from __future__ import annotations

import json

import pytest
from test_training import TASKS, config, synthetic_episode

from tvf.data.dataset import MOVES_FILE
from tvf.data.format import episode_name, write_episode
from tvf.train.jobs import gctn_job, vf_job
from tvf.train.trainer import TrainError, train


def _moves(folder, tasks=TASKS, seeds=(100000,), method="tvf-large"):
    for task in tasks:
        for seed in seeds:
            write_episode(folder / task / episode_name(seed), synthetic_episode(task, seed, "train"))
    (folder / MOVES_FILE).write_text(json.dumps({"moves": method}))
    return folder


def test_the_vf_trains_on_the_demos_and_every_own_move_episode(own_data, tmp_path):
    _moves(tmp_path / "moves" / "train", tasks=(*TASKS, "stack-tower"))  # other tasks are left out
    cfg = config(own_data, tmp_path / "run", extra_data=tmp_path / "moves", steps=2)
    job = vf_job(cfg)
    train(cfg, job)
    record = json.loads((tmp_path / "run" / "config.json").read_text())
    assert record["extra_data"] == str(tmp_path / "moves")
    assert record["extra_episodes"] == [[t, 100000] for t in TASKS]
    assert sorted(record["episodes"]) == sorted([t, s] for t in TASKS for s in (0, 2))  # the demos as before
    assert {f"extra:{t}/100000" for t in TASKS} <= set(record["data_content"]["episodes"])


def test_extra_data_is_refused_where_it_does_not_belong(own_data, tmp_path):
    moves = _moves(tmp_path / "moves")
    with pytest.raises(TrainError, match="VF and latent runs only"):
        gctn_job(config(own_data, tmp_path / "g", extra_data=moves))
    with pytest.raises(TrainError, match="not demonstrations: give the demonstrations as --data"):
        vf_job(config(moves, tmp_path / "v"))
    with pytest.raises(TrainError, match="holds demonstrations, not a method's own moves"):
        vf_job(config(own_data, tmp_path / "v", extra_data=own_data / "train"))
    with pytest.raises(TrainError, match="no episodes of the run's tasks"):
        other = _moves(tmp_path / "other", tasks=("stack-tower",))
        vf_job(config(own_data, tmp_path / "v", extra_data=other))
    with pytest.raises(TrainError, match="--extra-data: .*no such dataset"):
        vf_job(config(own_data, tmp_path / "v", extra_data=tmp_path / "missing"))
