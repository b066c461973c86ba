"""Closed-loop evaluation: outputs, resume, intervals."""

import json

import pytest

from tvf.errors import TvfError
from tvf.evaluate.closed_loop import evaluate, wilson
from tvf.policies import PolicySpec


def test_wilson_interval():
    lo, hi = wilson(10, 20)
    assert lo == pytest.approx(0.299, abs=1e-3) and hi == pytest.approx(0.701, abs=1e-3)
    assert wilson(0, 20)[0] == 0.0 and wilson(20, 20)[1] == 1.0


def test_oracle_evaluation_writes_outputs_and_resumes(tmp_path, capsys):
    spec = PolicySpec("oracle")
    summary = evaluate(spec, ["stack-stair"], 1, 1, 1, tmp_path)
    assert summary["average"]["success"] == 1.0
    lines = (tmp_path / "episodes.jsonl").read_text().splitlines()
    assert len(lines) == 1 and json.loads(lines[0])["seed"] == 1
    assert "| stack-stair | 1 | 100.0% |" in (tmp_path / "summary.md").read_text()
    evaluate(spec, ["stack-stair"], 1, 1, 1, tmp_path)
    assert len((tmp_path / "episodes.jsonl").read_text().splitlines()) == 1  # nothing re-run
    assert "resuming" in capsys.readouterr().out
    with pytest.raises(TvfError, match="other step_slack"):  # the changed setting is named
        evaluate(spec, ["stack-stair"], 1, 1, 1, tmp_path, step_slack=2)


def test_gctn_needs_a_checkpoint(tmp_path, monkeypatch):
    import tvf.weights

    monkeypatch.setattr(tvf.weights, "WEIGHTS_DIR", tmp_path)  # no shipped weights
    with pytest.raises(TvfError, match="--gctn RUN"):
        evaluate(PolicySpec("gctn"), ["stack-stair"], 1, 1, 1, tmp_path)
    with pytest.raises(TvfError, match="does not exist"):
        evaluate(PolicySpec("gctn", gctn=str(tmp_path / "nope")), ["stack-stair"], 1, 1, 1, tmp_path / "b")
