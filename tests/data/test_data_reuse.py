"""Starting a dataset from another demo count's (reuse_episodes) and the memory rule of load_all."""

from __future__ import annotations

import errno
import os

import numpy as np
import pytest
from data_factory import make_episode

from tvf.data import GenerationPlan, generate, open_dataset
from tvf.data import dataset as dataset_module
from tvf.data.dataset import FAILURES, image_bytes
from tvf.data.format import DataError, LazyFrames, episode_name, write_episode
from tvf.data.generation import Outcome, read_failures, reuse_episodes
from tvf.io import append_jsonl, temp_path
from tvf.tasks import Task

TASK = "stack-stair"


def write_source(folder, seeds, failures=(), task=TASK):
    """A train split folder with small episodes at ``seeds`` and recorded failures at ``failures``."""
    for seed in seeds:
        ep = make_episode(task, seed, steps=2, rng_seed=seed)
        write_episode(folder / task / episode_name(seed), ep)
    for seed in failures:
        append_jsonl(folder / FAILURES, {"task": task, "seed": seed, "split": "train", "reason": "fake"})


def test_a_smaller_plan_takes_the_first_episodes_by_seed(tmp_path):
    source = tmp_path / "big" / "train"
    write_source(source, [0, 2, 6, 8], failures=[4])
    plan = GenerationPlan((TASK,), "train", 2, tmp_path / "small")
    assert reuse_episodes(source, plan) == 2
    kept = sorted(p.name for p in (plan.folder / TASK).iterdir())
    assert kept == [episode_name(0), episode_name(2)]
    assert os.path.samefile(plan.folder / TASK / episode_name(0), source / TASK / episode_name(0))
    assert not (plan.folder / FAILURES).exists()  # seed 4 is past the two episodes
    assert reuse_episodes(source, plan) == 0  # again: nothing more


def test_a_larger_plan_is_completed_by_generation_only(tmp_path):
    source = tmp_path / "small" / "train"
    write_source(source, [0, 2, 6], failures=[4])
    plan = GenerationPlan((TASK,), "train", 5, tmp_path / "big")
    assert reuse_episodes(source, plan) == 3
    assert set(read_failures(plan.folder)) == {(TASK, 4)}
    ran = []

    def job(task: Task, split: str, seed: int, folder: str) -> Outcome:
        ran.append(seed)
        final = plan.folder / task.name / episode_name(seed)
        tmp = temp_path(final)
        write_episode(tmp, make_episode(task.name, seed, steps=2, rng_seed=seed))
        return Outcome(task.name, seed, True, steps=2, tmp=str(tmp))

    report = generate(plan, 1, progress=False, job=job, log=lambda s: None)
    assert ran == [8, 10] and (report.skipped, report.generated) == (3, 2)
    assert [e.seed for e in open_dataset(plan.folder).episodes[TASK]] == [0, 2, 6, 8, 10]


def test_the_walk_stops_at_a_seed_the_source_has_not_settled(tmp_path):
    source = tmp_path / "odd" / "train"
    write_source(source, [0, 4])  # seed 2 neither kept nor failed: not a prefix of a generation
    plan = GenerationPlan((TASK,), "train", 2, tmp_path / "new")
    assert reuse_episodes(source, plan) == 1
    assert [p.name for p in (plan.folder / TASK).iterdir()] == [episode_name(0)]
    assert reuse_episodes(tmp_path / "missing", plan) == 0


def test_episodes_are_copied_where_links_fail(tmp_path, monkeypatch):
    source = tmp_path / "a" / "train"
    write_source(source, [0])

    def no_links(src, dst):
        raise OSError(errno.EXDEV, "cross-device link")

    monkeypatch.setattr(os, "link", no_links)
    plan = GenerationPlan((TASK,), "train", 1, tmp_path / "b")
    assert reuse_episodes(source, plan) == 1
    copy = plan.folder / TASK / episode_name(0)
    assert not os.path.samefile(copy, source / TASK / episode_name(0))
    assert copy.read_bytes() == (source / TASK / episode_name(0)).read_bytes()
    assert not list(plan.folder.glob(f"{TASK}/.*"))  # no temporary file left


def test_another_split_is_refused(tmp_path):
    source = tmp_path / "x" / "test"
    write_episode(source / TASK / episode_name(1), make_episode(TASK, 1, steps=2, split="test"))
    with pytest.raises(DataError, match="split"):
        reuse_episodes(source, GenerationPlan((TASK,), "train", 1, tmp_path / "y"))


def test_load_all_leaves_large_sets_on_disk(tmp_path, monkeypatch):
    write_source(tmp_path / "train", [0, 2])
    ds = open_dataset(tmp_path / "train")
    h, w = 160, 160
    assert image_bytes(ds.infos()) == 2 * 3 * h * w * 7  # 3 frames each, uint8 colour + float32 height
    eager = ds.load_all()
    assert isinstance(eager[0].color, np.ndarray)
    monkeypatch.setattr(dataset_module, "EAGER_IMAGE_BYTES", image_bytes(ds.infos()) - 1)
    lazy = ds.load_all()
    assert isinstance(lazy[0].color, LazyFrames) and isinstance(lazy[1].height, LazyFrames)
    assert np.array_equal(lazy[1].color[2], eager[1].color[2])
    assert isinstance(ds.load_all(lazy=False)[0].color, np.ndarray)
