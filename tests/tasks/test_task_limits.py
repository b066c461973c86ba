"""Task files checked at load time against the workspace, the arm's reach and the height range (issue 16,
case 6): the error names the file, the task and the target; accepted tasks always lay out in full."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_run import run

from tvf.geometry import EDGE_MARGIN, REACH, WORKSPACE, rotate_xy
from tvf.tasks import (
    BLOCK_RADIUS,
    BLOCK_SIZE,
    BUILTIN,
    CELL_RADIUS,
    CELL_THICKNESS,
    TaskError,
    load_tasks,
    placement_problem,
)


def task_file(tmp_path, targets, base="stand_1", name="mine"):
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps({"tasks": {name: {"split": "unseen", "base": base, "targets": targets}}}))
    return path


def refused(tmp_path, targets, **kw) -> str:
    path = task_file(tmp_path, targets, **kw)
    with pytest.raises(TaskError) as err:
        load_tasks(path)
    message = str(err.value)
    assert message.startswith(f"{path}: task 'mine': ") and "\n" not in message
    return message


def test_every_builtin_task_is_within_the_limits():
    for task in BUILTIN.tasks:
        centres, radii = task.discs()
        assert placement_problem(centres, radii) is None, task.name


def test_a_target_above_the_height_range_is_refused():
    # layer 5's top is at 24.5 cm, layer 6's at 28.5 cm: above the 28 cm range of the height map
    assert CELL_THICKNESS + 6 * BLOCK_SIZE <= WORKSPACE.z_max < CELL_THICKNESS + 7 * BLOCK_SIZE


def test_height_layer_six_refused_layer_five_accepted(tmp_path):
    message = refused(tmp_path, [[0, 0, k] for k in range(7)])
    assert "target 6 [0.0, 0.0, 6]" in message and "above the 28 cm height range" in message
    assert "layers 0-5 fit" in message
    assert load_tasks(task_file(tmp_path, [[0, 0, k] for k in range(6)])).get("mine").n_blocks == 6


@pytest.mark.parametrize("x, y", [(0.6, 0.0), (0.0, -0.6), (0.45, 0.45)])
def test_a_target_outside_the_workspace_is_refused_and_named(tmp_path, x, y):
    message = refused(tmp_path, [[0, 0, 0], [x, y, 0], [0, 0, 1]])
    assert f"target 1 [{float(x)}, {float(y)}, 0] lies outside the workspace" in message


def test_a_target_out_of_reach_is_refused_and_named(tmp_path):
    # 0.54 m from the base fits the workspace diagonally, but not inside the reach ring as well
    centres = np.array([[0, 0], [0, 0.54]])
    radii = np.array([CELL_RADIUS, BLOCK_RADIUS])
    assert placement_problem(centres, radii, reach=(0.0, 10.0)) is None
    message = refused(tmp_path, [[0, 0, 0], [0, 0.54, 0]])
    assert "target 1 [0.0, 0.54, 0] is out of the arm's reach" in message
    assert f"{REACH[0]:.2f}-{REACH[1]:.2f} m" in message


def test_the_target_that_breaks_the_structure_is_named(tmp_path):
    # each far target fits alone on its side of the base; together they span too much: the second is named
    message = refused(tmp_path, [[0, 0, 0], [0.3, 0, 0], [-0.3, 0, 0]])
    assert "target 2 [-0.3, 0.0, 0]" in message


def test_a_base_too_large_for_the_workspace_is_refused(tmp_path):
    path = tmp_path / "big.json"
    for cells, problem in ((16, "lies outside the workspace"), (12, "is out of the arm's reach")):
        base = [[0.05 * i, 0.0, "brown"] for i in range(cells)]  # 0.8 m: never fits; 0.6 m: only diagonally
        task = {"split": "unseen", "base": "long", "targets": [[0, 0, 0]]}
        path.write_text(json.dumps({"bases": {"long": base}, "tasks": {"mine": task}}))
        with pytest.raises(TaskError, match=rf"base 'long' {problem}: no base pose keeps its cells"):
            load_tasks(path)


def test_tvf_tasks_refuses_the_file_in_one_line(tmp_path, capsys):
    path = task_file(tmp_path, [[0, 0, 0], [0.6, 0, 0]])
    code, _, err = run(capsys, "tasks", "--task-file", str(path))
    assert code == 2 and err.strip().count("\n") == 0
    assert str(path) in err and "target 1 [0.6, 0.0, 0]" in err


def test_an_accepted_far_target_always_lands_inside_the_workspace_and_reach(tmp_path):
    """A target 0.3 m from a one-cell base is accepted; every sampled layout keeps it in the image."""
    from tvf.sim.world import SceneConfig, sample_layout

    task = load_tasks(task_file(tmp_path, [[0, 0, 0], [0.3, 0, 0]])).get("mine")
    for seed in range(15):
        layout = sample_layout(task, np.random.default_rng(seed), SceneConfig())
        xy = rotate_xy(task.target_offsets()[:, :2], layout.base_yaw) + layout.base_xy
        assert WORKSPACE.contains_xy(xy, EDGE_MARGIN + BLOCK_RADIUS).all(), seed
        r = np.linalg.norm(xy, axis=1)
        assert ((r - BLOCK_RADIUS >= REACH[0]) & (r + BLOCK_RADIUS <= REACH[1])).all(), seed
