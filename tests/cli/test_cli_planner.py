"""The planner through the command line: tvf eval with TVF methods, tvf viz plan, tvf quickstart, errors."""

import json

import pytest
from cli_run import run

import tvf.weights
from tvf.models.checkpoint import save_checkpoint, save_weights
from tvf.models.gctn import GCTN
from tvf.models.presets import get_preset
from tvf.models.vf import VisualForesight


@pytest.fixture(scope="module")
def smoke_weights(tmp_path_factory):
    """Smoke-preset weights named as the shipped ones (safetensors), and as training checkpoints (.pt)."""
    folder = tmp_path_factory.mktemp("weights")
    preset = get_preset("smoke")
    for kind, model in (("gctn", GCTN(preset, seed=0)), ("vf", VisualForesight(preset, seed=0))):
        save_weights(folder / tvf.weights.shipped_name(kind), model)
        save_checkpoint(folder / f"{kind}-lite.pt", model)
    return folder


def test_eval_tvf_small_with_given_checkpoints(capsys, tmp_path, smoke_weights):
    code, out, err = run(
        capsys, "eval", "--method", "tvf-small", "--gctn", str(smoke_weights / "gctn-lite.pt"),
        "--vf", str(smoke_weights / "vf-lite.pt"), "--tasks", "stack-stair", "--episodes", "1",
        "--out", str(tmp_path / "eval"),
    )  # fmt: skip
    assert code == 0, err
    summary = json.loads((tmp_path / "eval" / "summary.json").read_text())
    assert summary["method"] == "tvf-small" and summary["average"]["episodes"] == 1
    episode = json.loads((tmp_path / "eval" / "episodes.jsonl").read_text())
    assert episode["steps"] == 3 and len(episode["actions"]) == 3
    assert json.loads((tmp_path / "eval" / "eval.json").read_text())["k"] is None


def test_viz_plan_draws_every_node_of_a_custom_tree(capsys, tmp_path, smoke_weights):
    code, out, err = run(
        capsys, "viz", "plan", "--task", "stack-stair", "--k", "2", "--depth", "2", "--out", str(tmp_path),
        "--gctn", str(smoke_weights / "gctn-lite.pt"), "--vf", str(smoke_weights / "vf-lite.pt"),
    )  # fmt: skip
    assert code == 0, err
    assert (tmp_path / "plan.png").read_bytes()[:4] == b"\x89PNG"
    plan = json.loads((tmp_path / "plan.json").read_text())
    depths = [n["depth"] for n in plan["nodes"]]
    assert set(depths) == {1, 2} and depths.count(1) <= 2 and depths.count(2) <= 4
    assert plan["path"][-1] == plan["best"] and plan["counts"]["gctn_calls"] == 2


def test_quickstart_uses_the_shipped_weights(capsys, tmp_path, smoke_weights, monkeypatch):
    monkeypatch.setattr(tvf.weights, "WEIGHTS_DIR", smoke_weights)
    code, out, err = run(
        capsys, "quickstart", "--tasks", "stack-stair", "--episodes", "1", "--workers", "1",
        "--out", str(tmp_path),
    )  # fmt: skip
    assert code == 0, err
    assert "TVF-L" in out and (tmp_path / "report.html").exists()
    assert (tmp_path / "gifs" / "stack-stair-0.gif").read_bytes()[:6] == b"GIF89a"
    assert "stack-stair" in (tmp_path / "report.md").read_text()


def test_missing_shipped_weights_and_wrong_checkpoints_are_one_line_errors(
    capsys, tmp_path, smoke_weights, monkeypatch
):
    monkeypatch.setattr(tvf.weights, "WEIGHTS_DIR", tmp_path)
    code, _, err = run(capsys, "quickstart", "--out", str(tmp_path / "q"))
    assert code == 2 and "shipped gctn weights" in err and "make reproduce" in err
    assert err.strip().count("\n") == 0
    code, _, err = run(
        capsys, "eval", "--method", "tvf-large", "--gctn", str(smoke_weights / "gctn-lite.pt"),
        "--vf", str(smoke_weights / "gctn-lite.pt"), "--out", str(tmp_path / "e"),
    )  # fmt: skip
    assert code == 2 and "expected 'vf'" in err
    code, _, err = run(capsys, "eval", "--method", "tvf-large", "--k", "0", "--out", str(tmp_path / "k"))
    assert code == 2 and "k >= 1" in err


def test_viz_gctn_defaults_to_the_shipped_weights(capsys, tmp_path, smoke_weights, monkeypatch):
    monkeypatch.setattr(tvf.weights, "WEIGHTS_DIR", smoke_weights)
    code, out, err = run(capsys, "viz", "gctn", "--task", "stack-stair", "--out", str(tmp_path))
    assert code == 0, err
    assert (tmp_path / "gctn_decision.png").exists() and (tmp_path / "gctn_maps.npz").exists()
