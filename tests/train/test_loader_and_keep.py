"""Batches built by DataLoader workers (`--loader-workers`) and checkpoint retention (`--keep`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch
from data_factory import make_episode

import tvf.train.trainer as trainer
from tvf.data.format import episode_name, write_episode
from tvf.models.checkpoint import load_checkpoint
from tvf.runs import RunDir
from tvf.train.config import TrainConfig
from tvf.train.jobs import gctn_job, vf_job
from tvf.train.trainer import TrainError, check_config, prune_checkpoints, step_batches, train

TASKS = ("stack-stair", "put-t")


@pytest.fixture(scope="module")
def data_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("demos")
    for task in TASKS:
        for seed in (0, 2):
            write_episode(root / task / episode_name(seed), make_episode(task, seed, steps=4, rng_seed=seed))
    return root


def config(data_root: Path, out: Path, **kw) -> TrainConfig:
    base = TrainConfig(
        data=data_root, out=out, preset="smoke", demos=2, tasks=",".join(TASKS), lr=1e-3, batch=2, steps=4,
        schedule="constant", warmup=0, log_every=1, checkpoint_every=1, images_every=0, progress=False,
    )  # fmt: skip
    return replace(base, **kw)


def step_files(run: Path) -> list[str]:
    return sorted(p.name for p in (run / "checkpoints").iterdir())


QUIET = pytest.mark.filterwarnings("ignore:This DataLoader will create")  # more workers than cores


@QUIET
def test_loader_workers_build_the_same_batches_as_the_training_thread(data_root, tmp_path):
    for job_of in (gctn_job, vf_job):
        cfg = config(data_root, tmp_path / "run", steps=5)
        job = job_of(cfg)
        here = list(step_batches(cfg, job, 1, None))  # steps 2..5, as a run resumed at step 1 draws them
        there = list(step_batches(replace(cfg, loader_workers=2), job, 1, None))
        assert len(here) == len(there) == 4
        for a, b in zip(here, there, strict=True):
            assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
        half = list(step_batches(replace(cfg, loader_workers=1), job, 1, slice(1, 2)))
        assert all(torch.equal(a[k][1:2], b[k]) for a, b in zip(here, half, strict=True) for k in a)


@QUIET
@pytest.mark.slow  # loader processes: about 12 s
def test_a_run_with_loader_workers_trains_the_same_weights(data_root, tmp_path):
    plain = config(data_root, tmp_path / "plain", steps=3, checkpoint_every=3)
    workers = replace(plain, out=tmp_path / "workers", loader_workers=2)
    train(plain, gctn_job(plain))
    train(workers, gctn_job(workers))
    a = load_checkpoint(tmp_path / "plain" / "checkpoints" / "last.pt", "gctn").model
    b = load_checkpoint(tmp_path / "workers" / "checkpoints" / "last.pt", "gctn").model
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.slow  # a run resumed three times; the deletion rule itself is tested below
def test_keep_leaves_the_newest_step_checkpoints_and_last(data_root, tmp_path):
    cfg = config(data_root, tmp_path / "run", keep=2)
    train(cfg, gctn_job(cfg))
    assert step_files(cfg.out) == ["last.pt", "step_000003.pt", "step_000004.pt"]
    assert load_checkpoint(cfg.out / "checkpoints" / "last.pt", "gctn").step == 4
    longer = replace(cfg, steps=6, keep=1, resume=True)  # a resumed run prunes what the first one kept
    train(longer, gctn_job(longer))
    assert step_files(cfg.out) == ["last.pt", "step_000006.pt"]
    everything = config(data_root, tmp_path / "all", steps=3)  # --keep 0, the default: keep all
    train(everything, gctn_job(everything))
    assert step_files(everything.out) == ["last.pt", "step_000001.pt", "step_000002.pt", "step_000003.pt"]


def test_keep_deletes_nothing_before_the_new_checkpoint_is_written(data_root, tmp_path, monkeypatch):
    cfg = config(data_root, tmp_path / "run", keep=1)
    write = trainer.save_checkpoint

    def fails_at_step_3(path, model, optimizer, step, *args):
        if step == 3:
            raise RuntimeError("the write of step 3 failed")
        return write(path, model, optimizer, step, *args)

    monkeypatch.setattr(trainer, "save_checkpoint", fails_at_step_3)
    with pytest.raises(RuntimeError, match="step 3"):
        train(cfg, gctn_job(cfg))
    assert step_files(cfg.out) == ["last.pt", "step_000002.pt"]  # step 2 stays until step 3 exists
    assert load_checkpoint(cfg.out / "checkpoints" / "last.pt", "gctn").step == 2


def test_prune_ignores_other_files_and_bad_counts_are_refused(data_root, tmp_path):
    run = RunDir(tmp_path / "run")
    run.checkpoints.mkdir(parents=True)
    for name in ("step_000010.pt", "step_000002.pt", "step_000100.pt", "last.pt", "notes.txt", "step_x.pt"):
        (run.checkpoints / name).write_bytes(b"")
    assert [s for s, _ in run.step_checkpoints()] == [2, 10, 100]
    assert prune_checkpoints(run, 0) == []
    assert [p.name for p in prune_checkpoints(run, 1)] == ["step_000002.pt", "step_000010.pt"]
    assert sorted(p.name for p in run.checkpoints.iterdir()) == [
        "last.pt", "notes.txt", "step_000100.pt", "step_x.pt"]  # fmt: skip
    for flag in ("keep", "loader_workers"):
        with pytest.raises(TrainError, match=f"--{flag.replace('_', '-')} must be 0"):
            check_config(config(data_root, tmp_path / "bad", **{flag: -1}))
