"""The world commands, called through the real entry point."""

import json

import numpy as np
import pytest
from cli_run import run


def test_tasks_json_lists_the_fourteen(capsys):
    code, out, _ = run(capsys, "tasks", "--json")
    rows = json.loads(out)
    assert code == 0 and len(rows) == 14
    assert {"name", "split", "blocks", "horizon"} <= set(rows[0])


def test_unknown_task_is_one_line_and_exit_2(capsys):
    code, _, err = run(capsys, "oracle", "--tasks", "stack-moon")
    assert code == 2
    assert err.strip().count("\n") == 0
    assert "unknown task 'stack-moon'" in err and "stack-tower" in err


def test_malformed_task_file_is_one_line_and_exit_2(capsys, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("tasks:\n  x:\n    split: train\n    base: stand_9\n    targets: [[0, 0, 0]]\n")
    code, _, err = run(capsys, "tasks", "--task-file", str(bad))
    assert code == 2 and "unknown base 'stand_9'" in err and str(bad) in err


def test_task_file_adds_a_task(capsys, tmp_path):
    extra = tmp_path / "extra.json"
    extra.write_text(
        json.dumps(
            {
                "tasks": {
                    "my-pair": {"split": "unseen", "base": "stand_2", "targets": [[0, 0, 0], [0, 0.05, 0]]}
                }
            }
        )
    )
    code, out, _ = run(capsys, "tasks", "--task-file", str(extra))
    assert code == 0 and "my-pair" in out


def test_render_writes_images_and_arrays(capsys, tmp_path):
    code, _, _ = run(capsys, "render", "--task", "stack-stair", "--seed", "4", "--out", str(tmp_path))
    assert code == 0
    for name in ("initial", "goal"):
        arrays = np.load(tmp_path / f"{name}.npz")
        assert arrays["color"].shape == (160, 160, 3) and arrays["color"].dtype == np.uint8
        assert arrays["height"].shape == (160, 160) and arrays["height"].dtype == np.float32
        assert (tmp_path / f"{name}.png").stat().st_size > 0
    assert (tmp_path / "perspective.png").stat().st_size > 0
    goal = np.load(tmp_path / "goal.npz")["height"]
    assert goal.max() == pytest.approx(0.085, abs=0.003)  # two layers on a 5 mm base


def test_render_to_unwritable_directory(capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    code, _, err = run(capsys, "render", "--task", "stack-stair", "--out", str(blocker / "sub"))
    assert code == 2 and "cannot write to output directory" in err


def test_oracle_reports_success_and_writes_json(capsys, tmp_path):
    out = tmp_path / "oracle.json"
    code, text, _ = run(
        capsys, "oracle", "--tasks", "stack-stair", "--episodes", "1", "--seed-start", "3", "--json", str(out)
    )
    assert code == 0 and "stack-stair" in text
    doc = json.loads(out.read_text())
    assert doc["tasks"][0]["success"] == 1.0
    assert doc["episodes"][0]["seed"] == 3 and len(doc["episodes"][0]["actions"]) == 3
