"""A real `tvf experiment` sweep with the smoke preset: 2 demo counts x 2 seeds, then a re-run (slow: 13 min
of wall time on the shared 2-core machine, mostly PyBullet episodes and smoke training)."""

from __future__ import annotations

import os

import pytest

from tvf.data.format import episode_name
from tvf.experiment.config import ExperimentConfig
from tvf.experiment.sweep import cell_dir, data_dir, run_experiments

TRAIN_TASK, TEST_TASK = "stack-tower", "stack-stair"


@pytest.mark.slow
def test_a_real_smoke_sweep(tmp_path):
    """The real pipeline, smoke models: 2 demo counts x 2 seeds, then a re-run that does nothing new."""
    cfg = ExperimentConfig(
        out=tmp_path, preset="smoke", test_demos=1, train_tasks=TRAIN_TASK, tasks=TEST_TASK, methods="gctn",
        episodes=1, workers=1, gifs=0, stages="data,train,eval,report",
    )  # fmt: skip
    run_experiments(cfg, (1, 2), (0, 1))
    logs = {(d, s): (cell_dir(tmp_path, d, s) / "eval" / "gctn" / "episodes.jsonl").read_text()
            for d in (1, 2) for s in (0, 1)}  # fmt: skip
    ckpt = cell_dir(tmp_path, 2, 1) / "gctn" / "checkpoints" / "last.pt"
    stamp = ckpt.stat().st_mtime_ns
    assert os.path.samefile(data_dir(tmp_path, 1) / "train" / TRAIN_TASK / episode_name(0),
                            data_dir(tmp_path, 2) / "train" / TRAIN_TASK / episode_name(0))  # fmt: skip
    run_experiments(cfg, (1, 2), (0, 1))
    assert ckpt.stat().st_mtime_ns == stamp
    assert all((cell_dir(tmp_path, d, s) / "eval" / "gctn" / "episodes.jsonl").read_text() == log
               for (d, s), log in logs.items())  # fmt: skip
    assert "| cells finished | 4 of 4 |" in (tmp_path / "sweep.md").read_text()
