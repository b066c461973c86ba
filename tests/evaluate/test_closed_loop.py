"""Closed-loop evaluation: outputs, resume, intervals."""

import json

import pytest

from tvf.errors import TvfError
from tvf.evaluate.closed_loop import evaluate, miss_counts, summarise, summary_markdown, wilson
from tvf.policies import PolicySpec
from tvf.sim.success import MISS_KINDS


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


def test_a_resume_is_refused_when_a_methods_default_changed_since(tmp_path, monkeypatch):
    from dataclasses import replace

    from tvf.models.checkpoint import save_checkpoint
    from tvf.models.gctn import GCTN
    from tvf.models.presets import SMOKE
    from tvf.policies import registry

    weights, out = tmp_path / "gctn.pt", tmp_path / "eval"
    save_checkpoint(weights, GCTN(SMOKE, seed=0))
    spec = PolicySpec("gctn", gctn=str(weights))  # turns left to the method: recorded resolved
    evaluate(spec, ["stack-stair"], 1, 1, 1, out)
    recorded = json.loads((out / "eval.json").read_text())
    assert recorded["turns"] is None and recorded["resolved"]["turns"] == registry.METHODS["gctn"].turns
    changed = replace(registry.METHODS["gctn"], turns=1)
    monkeypatch.setitem(registry.METHODS, "gctn", changed)  # a later tvf whose default is another
    with pytest.raises(TvfError, match=r"other turns \(4 → 1\).*--restart"):
        evaluate(spec, ["stack-stair"], 1, 1, 1, out)
    del recorded["resolved"]  # a folder from before the record resumes on the spec's own values
    (out / "eval.json").write_text(json.dumps(recorded))
    evaluate(spec, ["stack-stair"], 1, 1, 1, out)


def test_the_resolved_settings_fill_in_the_planner_and_name_a_changed_default(tmp_path, monkeypatch):
    from tvf.evaluate.closed_loop import _changed_settings
    from tvf.policies import resolved_settings

    large = resolved_settings(PolicySpec("tvf-large"))
    assert large["k"] == 3 and large["proposals"] == "nms" and large["turns"] == 8 and "batched" not in large
    assert resolved_settings(PolicySpec("tvf-large", k=2))["pick_branches"] == 2  # a smaller K, fewer picks
    assert resolved_settings(PolicySpec("oracle")) == {}
    meta = {"method": "tvf-large", "resolved": large, "weights": {}}
    old = tmp_path / "eval.json"
    old.write_text(json.dumps({**meta, "resolved": {**large, "depth": 2, "gone": 1}}))
    assert _changed_settings(old, meta) == ["depth (2 → 3)"]  # keys only one side has are not changes


def test_records_say_how_the_unfilled_targets_are_missed(tmp_path):
    from tvf.evaluate.runner import run_episode
    from tvf.policies import make_policy
    from tvf.sim.factory import sim_env
    from tvf.tasks import get_task

    summary = evaluate(PolicySpec("oracle"), ["stack-stair"], 1, 1, 1, tmp_path)
    record = json.loads((tmp_path / "episodes.jsonl").read_text())
    assert record["success"] and record["misses"] == []  # a finished structure misses nothing
    assert summary["misses"] == {"failed": 0, "one_target": 0, "targets": dict.fromkeys(MISS_KINDS, 0),
                                 "tasks": {}}  # fmt: skip
    env = sim_env(get_task("stack-stair"))
    cut = run_episode(env, 1, make_policy(PolicySpec("oracle"), env), max_steps=1)  # one block of six
    assert not cut.success and len(cut.misses) == env.task.n_blocks - 1
    assert {m["kind"] for m in cut.misses} == {"away"}  # the other blocks still lie where they spawned


def test_the_summary_counts_the_misses_of_the_failed_episodes():
    turn = {"target": 0, "xy_mm": 2.0, "z_mm": 0.0, "yaw_deg": 22.0, "kind": "turn"}
    level = {"target": 3, "xy_mm": 4.0, "z_mm": 40.0, "yaw_deg": 1.0, "kind": "level"}
    records = [
        {"task": "put-t", "success": False, "progress": 0.5, "misses": [turn]},
        {"task": "put-t", "success": False, "progress": 0.5, "misses": [turn, level]},
        {"task": "put-t", "success": True, "progress": 1.0, "misses": []},
        {"task": "stack-stair", "success": False, "progress": 0.5},  # a record from before misses
    ]
    counts = miss_counts(records)
    assert counts["failed"] == 2 and counts["one_target"] == 1
    assert counts["targets"] == {"turn": 2, "offset": 0, "level": 1, "away": 0}
    text = summary_markdown(summarise(records, "gctn"))
    assert "Failed episodes: 2, 1 of them by one target" in text and "turn 2, offset 0, level 1" in text
    assert miss_counts([{"task": "put-t", "success": False, "progress": 0.0}]) is None
    assert "Failed episodes" not in summary_markdown(summarise(records[3:], "gctn"))
