import json

import numpy as np
import pytest

from tvf.tasks import TaskError, all_tasks, get_task, load_task_file, parse_task_table, resolve_tasks

# name -> (split, blocks, layers): facts §1.2-1.3
EXPECTED = {
    "stack-tower": ("train", 3, 3),
    "stack-t": ("train", 4, 3),
    "put-block-base": ("train", 3, 1),
    "stack-palace": ("train", 7, 3),
    "stack-square": ("train", 4, 2),
    "stack-pyramid": ("train", 6, 3),
    "put-t": ("unseen", 3, 1),
    "put-plane": ("unseen", 4, 1),
    "stack-rectangle": ("unseen", 6, 2),
    "stack-big-stair": ("unseen", 6, 3),
    "stack-stair": ("unseen", 3, 2),
    "stack-building": ("unseen", 5, 3),
    "stack-pallet": ("unseen", 8, 2),
    "stack-twin-tower": ("unseen", 6, 3),
}


def test_the_fourteen_tasks():
    tasks = all_tasks()
    assert list(tasks) == list(EXPECTED)
    for name, (split, blocks, layers) in EXPECTED.items():
        s = tasks[name].summary()
        assert (s["split"], s["blocks"], s["layers"], s["horizon"]) == (split, blocks, layers, blocks)


def test_targets_rest_at_true_height():
    z = get_task("stack-tower").target_offsets()[:, 2]
    assert np.allclose(z, [0.025, 0.065, 0.105])


def test_orders_cover_every_target_and_respect_supports():
    for task in all_tasks().values():
        supports = task.supports()
        for order in task.orders:
            done: set[int] = set()
            for group in order:
                for t in group:
                    assert all(s in done or s in group for s in supports[t]), (task.name, t)
                done.update(group)
            assert done == set(range(task.n_blocks))


def test_resolve_splits_and_lists():
    assert len(resolve_tasks("train")) == 6
    assert len(resolve_tasks("unseen")) == 8
    assert len(resolve_tasks("all")) == 14
    assert [t.name for t in resolve_tasks("put-t, stack-t")] == ["put-t", "stack-t"]


def test_unknown_task_names_the_choices():
    with pytest.raises(TaskError, match="unknown task 'stack-moon'.*stack-tower"):
        get_task("stack-moon")


def test_task_file_yaml_and_json(tmp_path):
    table = {
        "bases": {"strip": [[0, 0, "brown"], [0.05, 0, "brown"]]},
        "tasks": {
            "my-wall": {
                "split": "unseen",
                "base": "strip",
                "targets": [[0, 0, 0], [0.05, 0, 0], [0.025, 0, 1]],
            }
        },
    }
    (tmp_path / "t.json").write_text(json.dumps(table))
    yaml_text = (
        "tasks:\n  my-tower:\n    split: train\n    base: stand_1\n    targets: [[0, 0, 0], [0, 0, 1]]\n"
    )
    (tmp_path / "t.yaml").write_text(yaml_text)
    wall = load_task_file(tmp_path / "t.json")["my-wall"]
    assert wall.n_blocks == 3 and wall.supports()[2] == [0, 1]
    assert load_task_file(tmp_path / "t.yaml")["my-tower"].n_blocks == 2


@pytest.mark.parametrize(
    "spec, message",
    [
        ({"tasks": {"x": {"split": "train", "base": "nope", "targets": [[0, 0, 0]]}}}, "unknown base"),
        ({"tasks": {"x": {"split": "test", "base": "stand_1", "targets": [[0, 0, 0]]}}}, "split must be"),
        ({"tasks": {"x": {"split": "train", "base": "stand_1"}}}, "missing field"),
        ({"tasks": {"x": {"split": "train", "base": "stand_1", "targets": [[0, 0, 1]]}}}, "rests on nothing"),
        (
            {
                "tasks": {
                    "x": {"split": "train", "base": "stand_1", "targets": [[0, 0, 0]], "orders": [[[1]]]}
                }
            },
            "every",
        ),
        ({"nothing": 1}, "top-level 'tasks'"),
    ],
)
def test_malformed_tables_are_rejected(spec, message):
    with pytest.raises(TaskError, match=message):
        parse_task_table(spec, "file.yaml")


def test_unreadable_task_files(tmp_path):
    with pytest.raises(TaskError, match="does not exist"):
        load_task_file(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(TaskError, match="not valid json"):
        load_task_file(bad)
