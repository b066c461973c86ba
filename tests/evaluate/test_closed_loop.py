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


def test_a_resume_is_keyed_on_the_weights_content_not_their_path(tmp_path, capsys):
    from tvf.models.checkpoint import save_checkpoint
    from tvf.models.gctn import GCTN
    from tvf.models.presets import SMOKE

    weights, out = tmp_path / "gctn.pt", tmp_path / "eval"
    save_checkpoint(weights, GCTN(SMOKE, seed=0))
    spec = PolicySpec("gctn", gctn=str(weights))
    evaluate(spec, ["stack-stair"], 1, 1, 1, out)
    recorded = json.loads((out / "eval.json").read_text())["weights"]
    assert set(recorded) == {"gctn"} and len(recorded["gctn"]) == 64  # the file's SHA-256
    save_checkpoint(weights, GCTN(SMOKE, seed=1))  # other weights at the same path
    with pytest.raises(TvfError, match=r"other gctn weights \(content .{8}… → .{8}…\).*--restart"):
        evaluate(spec, ["stack-stair"], 1, 1, 1, out)
    capsys.readouterr()
    evaluate(spec, ["stack-stair"], 1, 1, 1, out, restart=True)  # starts over instead of resuming
    assert "resuming" not in capsys.readouterr().out
    assert len((out / "episodes.jsonl").read_text().splitlines()) == 1
    meta = json.loads((out / "eval.json").read_text())
    assert meta["weights"]["gctn"] != recorded["gctn"]
    del meta["weights"]  # a folder from before weights were hashed resumes on its paths
    (out / "eval.json").write_text(json.dumps(meta))
    evaluate(spec, ["stack-stair"], 1, 1, 1, out)
    assert "resuming: 1 of 1" in capsys.readouterr().out
