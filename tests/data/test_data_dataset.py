"""Opening datasets (split folder or root), the manifest, and the per-run demo subsets."""

from __future__ import annotations

import json

import pytest
from data_factory import make_episode

from tvf.data import DataError, demo_subset, open_dataset, write_episode, write_manifest
from tvf.data.dataset import MANIFEST, scan
from tvf.data.format import episode_name


def _dataset(root, tasks=("stack-tower", "stack-stair"), n=6, split="train"):
    for task in tasks:
        for i in range(n):
            seed = 2 * i + (split == "test")
            write_episode(root / split / task / episode_name(seed), make_episode(task, seed, 3, split, seed))
    return root / split


def test_open_split_or_root(tmp_path):
    folder = _dataset(tmp_path)
    ds = open_dataset(folder)
    assert ds.split == "train" and ds.tasks == ["stack-tower", "stack-stair"]  # task-table order
    assert len(ds) == 12 and ds.n_transitions() == 36 and ds.size_bytes() > 0
    assert [e.seed for e in ds.episodes["stack-stair"]] == [0, 2, 4, 6, 8, 10]
    assert open_dataset(tmp_path, split="train").root == folder
    assert open_dataset(tmp_path).root == folder  # only one split present
    _dataset(tmp_path, split="test", n=1)
    with pytest.raises(DataError, match="several splits"):
        open_dataset(tmp_path)
    assert open_dataset(tmp_path, split="test").split == "test"
    assert ds.load("stack-stair", 4).seed == 4
    with pytest.raises(DataError, match="no episode of task 'stack-stair' with seed 5"):
        ds.load("stack-stair", 5)
    with pytest.raises(DataError, match="no episodes of put-t"):
        open_dataset(folder, tasks=["put-t"])
    with pytest.raises(DataError, match="no such dataset directory"):
        open_dataset(tmp_path / "nothing")


def test_manifest_is_used_when_current_and_rebuilt_otherwise(tmp_path):
    folder = _dataset(tmp_path, n=2)
    write_manifest(scan(folder))
    doc = json.loads((folder / MANIFEST).read_text())
    assert doc["episodes"] == 4 and doc["tasks"]["stack-stair"]["transitions"] == 6
    assert len(doc["files"]) == 4 and doc["files"][0]["path"].endswith(".h5")
    write_episode(folder / "stack-stair" / episode_name(4), make_episode("stack-stair", 4, 3))
    assert len(open_dataset(folder)) == 5  # stale manifest: the files win
    (folder / MANIFEST).unlink()
    assert len(open_dataset(folder)) == 5


def test_manifest_of_another_version_is_refused(tmp_path):
    folder = _dataset(tmp_path, n=1)
    write_manifest(scan(folder))
    doc = json.loads((folder / MANIFEST).read_text())
    doc["format_version"] = 99
    (folder / MANIFEST).write_text(json.dumps(doc))
    with pytest.raises(DataError, match=r"manifest.json: dataset format version 99"):
        open_dataset(folder)


def test_misplaced_episode_is_refused(tmp_path):
    folder = _dataset(tmp_path, tasks=("stack-stair",), n=1)
    write_episode(folder / "stack-stair" / episode_name(1), make_episode("stack-stair", 1, 3, "test"))
    with pytest.raises(DataError, match="000001.h5: episode of split 'test'"):
        open_dataset(folder)


def test_demo_subsets_are_deterministic_and_nested(tmp_path):
    ds = open_dataset(_dataset(tmp_path))
    a = demo_subset(ds, 3, run_seed=0)
    assert demo_subset(ds, 3, run_seed=0) == a
    assert {t: len(v) for t, v in a.items()} == {"stack-tower": 3, "stack-stair": 3}
    runs = {tuple(e.seed for e in demo_subset(ds, 3, run_seed=r)["stack-stair"]) for r in range(6)}
    assert len(runs) > 1  # different runs draw different demos
    small = demo_subset(ds, 2, run_seed=0)
    for task in a:
        assert set(e.seed for e in small[task]) <= set(e.seed for e in a[task])
    only = demo_subset(ds, 3, run_seed=0, tasks=["stack-stair"])
    assert only["stack-stair"] == a["stack-stair"]  # independent of the other tasks
    with pytest.raises(DataError, match="has 6 episodes, 7 demos requested"):
        demo_subset(ds, 7, run_seed=0)
