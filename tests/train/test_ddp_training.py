"""Several training processes (torchrun, gloo on the CPU): each builds its slice of the global batch,
the gradients are averaged, rank 0 alone writes the run folder, and a resume is exact.

Two processes at global batch 4 must train like one process at batch 4 (losses per step within 2 %,
weight updates within 2 %); an interrupted two-process run resumed must equal the uninterrupted one.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from data_factory import make_episode

import tvf
from tvf.cli import main
from tvf.data.format import episode_name, write_episode
from tvf.errors import TvfError
from tvf.models.checkpoint import load_checkpoint
from tvf.models.gctn import GCTN
from tvf.models.presets import get_preset
from tvf.train.config import TrainConfig
from tvf.train.distributed import World, world_from_env
from tvf.train.jobs import gctn_job
from tvf.train.trainer import TrainError, check_config, step_batches, train

TASKS = ("stack-stair", "put-t")
FLAGS = ["--preset", "smoke", "--demos", "2", "--tasks", ",".join(TASKS), "--lr", "1e-3", "--batch", "4",
         "--log-every", "1", "--val-every", "4", "--val-samples", "2", "--images-every", "0",
         "--no-progress"]  # fmt: skip


@pytest.fixture(scope="module")
def data_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("demos")
    for split, seeds in (("train", (0, 2)), ("test", (1,))):
        for task in TASKS:
            for seed in seeds:
                episode = make_episode(task, seed, steps=4, split=split, rng_seed=seed)
                write_episode(root / split / task / episode_name(seed), episode)
    return root


def one_process(data_root: Path, out: Path, steps: int) -> TrainConfig:
    """The TrainConfig of `tvf train gctn --data ... FLAGS --steps N` (in this process)."""
    return TrainConfig(
        data=data_root, out=out, preset="smoke", demos=2, tasks=",".join(TASKS), lr=1e-3, batch=4,
        steps=steps, schedule="constant", warmup=0, log_every=1, val_every=4, val_samples=2,
        images_every=0, progress=False,
    )  # fmt: skip


def losses(run: Path) -> dict[int, float]:
    records = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    return {r["step"]: r["loss"] for r in records if r["split"] == "train"}


def weights(run: Path) -> dict[str, torch.Tensor]:
    return load_checkpoint(run / "checkpoints" / "last.pt", "gctn").model


def flat(state: dict[str, torch.Tensor]) -> torch.Tensor:
    return torch.cat([v.reshape(-1).double() for k, v in sorted(state.items()) if v.is_floating_point()])


def assert_trains_like_one_process(run: Path, data_root: Path, tmp_path: Path) -> None:
    """``run`` (two processes at global batch 4) against one process at batch 4: the same loss per
    step within 2 % and the same weight update within 2 % (training on a half batch is ~120 % off)."""
    one = tmp_path / "one"
    train(one_process(data_root, one, 4), gctn_job(one_process(data_root, one, 4)))
    a, b = losses(one), losses(run)
    assert list(b) == [1, 2, 3, 4]  # every step logged once: only rank 0 wrote metrics.jsonl
    assert all(abs(b[s] - a[s]) <= 0.02 * abs(a[s]) for s in a), (a, b)
    start = flat(GCTN(get_preset("smoke"), seed=0).state_dict())
    moved_one, moved_two = flat(weights(one)) - start, flat(weights(run)) - start
    assert moved_one.norm() > 0
    assert (moved_two - moved_one).norm() <= 0.02 * moved_one.norm()
    config = json.loads((run / "config.json").read_text())
    assert config["processes"] == 2 and config["batch"] == 4 and config["device"] == "cpu"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ddp_sessions(rank: int, port: int, data_root: Path, root: Path) -> None:
    """One of two processes: an uninterrupted 4-step run, and a run interrupted in step 3 then resumed."""
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE="2",
                      LOCAL_RANK=str(rank))  # fmt: skip
    torch.set_num_threads(1)
    dist.init_process_group("gloo", rank=rank, world_size=2)  # the trainer joins this group
    try:
        flags = ["--data", str(data_root), *FLAGS, "--checkpoint-every", "2"]
        main(["train", "gctn", "--out", str(root / "full"), "--steps", "4", *flags])
        part = replace(one_process(data_root, root / "part", 4), checkpoint_every=2)
        job = gctn_job(part)
        draw, calls = job.train_batch, []

        def interrupted(rng, share):
            calls.append(1)
            if len(calls) == 3:  # both processes stop during step 3 (step 2 was checkpointed)
                raise KeyboardInterrupt
            return draw(rng, share)

        job.train_batch = interrupted
        try:
            train(part, job)
        except KeyboardInterrupt:
            pass
        else:
            raise AssertionError("the interrupted session ran to its end")
        main(["train", "gctn", "--out", str(root / "part"), "--steps", "4", "--resume", *flags])
    finally:
        dist.destroy_process_group()


@pytest.mark.slow  # two ranks trained twice: about 30 s on 2 cores
def test_two_processes_train_like_one_and_resume_exactly(data_root, tmp_path):
    mp.spawn(_ddp_sessions, args=(_free_port(), data_root, tmp_path), nprocs=2, join=True)
    full, part = tmp_path / "full", tmp_path / "part"
    assert_trains_like_one_process(full, data_root, tmp_path)
    assert sorted(p.name for p in (full / "checkpoints").iterdir()) == [
        "last.pt", "step_000002.pt", "step_000004.pt"]  # fmt: skip
    a, b = weights(full), weights(part)
    assert all(torch.equal(a[k], b[k]) for k in a)  # the interrupted run resumed to the same weights
    last = Path("checkpoints") / "last.pt"
    assert (full / last).read_bytes() == (part / last).read_bytes()  # and the same optimiser state
    assert losses(full) == losses(part)
    assert load_checkpoint(part / "checkpoints" / "last.pt", "gctn").step == 4


@pytest.mark.slow  # three fresh interpreters (torchrun and two ranks): about 20 s of CPU
def test_torchrun_runs_tvf_train_with_loader_workers_and_keep(data_root, tmp_path):
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": os.pathsep.join(
        [str(Path(tvf.__file__).parents[1]), os.environ.get("PYTHONPATH", "")])}  # fmt: skip
    run = tmp_path / "two"
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
               "-m", "tvf", "train", "gctn", "--data", str(data_root), "--out", str(run), "--steps", "4",
               *FLAGS, "--checkpoint-every", "1", "--keep", "1", "--loader-workers", "1"]  # fmt: skip
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("done: ") == 1  # rank 0 alone reports
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["last.pt", "step_000004.pt"]
    assert_trains_like_one_process(run, data_root, tmp_path)
    bad = subprocess.run([*command[:-6], "--batch", "3", "--out", str(tmp_path / "bad")], env=env,
                         capture_output=True, text=True, timeout=900)  # fmt: skip
    assert bad.returncode != 0 and "--batch 3 does not split over 2 processes" in bad.stderr


def test_the_world_comes_from_torchrun_variables():
    assert world_from_env({}) == World()  # no torchrun: one process, as before
    world = world_from_env({"WORLD_SIZE": "4", "RANK": "3", "LOCAL_RANK": "1"})
    assert (world.rank, world.size, world.local_rank, world.main) == (3, 4, 1, False)
    assert World(0, 1).share(8) is None
    shares = [World(r, 4).share(8) for r in range(4)]
    assert [list(range(8))[s] for s in shares] == [[0, 1], [2, 3], [4, 5], [6, 7]]
    for bad in ({"WORLD_SIZE": "two"}, {"WORLD_SIZE": "2", "RANK": "2"}):
        with pytest.raises(TvfError, match="torchrun"):
            world_from_env(bad)


def test_a_batch_that_does_not_split_over_the_processes_is_refused(data_root, tmp_path, monkeypatch):
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("RANK", "0")
    cfg = replace(one_process(data_root, tmp_path / "run", 2), batch=3)
    with pytest.raises(TvfError, match=r"--batch 3 does not split over 2 processes.*divisible by 2"):
        check_config(cfg)
    check_config(replace(cfg, batch=4))
    monkeypatch.delenv("WORLD_SIZE")
    check_config(cfg)  # one process takes any batch
    with pytest.raises(TrainError, match="--keep must be 0"):
        check_config(replace(cfg, keep=-1))


def test_each_process_builds_exactly_its_slice_of_the_global_batch(data_root, tmp_path):
    cfg = one_process(data_root, tmp_path / "run", 3)
    job = gctn_job(cfg)
    whole = list(step_batches(cfg, job, 0, None))
    for rank in range(2):
        share = World(rank, 2).share(cfg.batch)
        mine = list(step_batches(cfg, job, 0, share))
        for full, part in zip(whole, mine, strict=True):
            assert {k: len(v) for k, v in part.items()} == {k: 2 for k in full}  # built only its half
            assert all(torch.equal(full[k][share], part[k]) for k in full)
    assert not torch.equal(whole[0]["current_color"], whole[1]["current_color"])  # a new batch each step
