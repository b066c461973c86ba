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


def shipped_record() -> dict:
    """A provenance record with numbers of its own (the report must show these, not built-in ones)."""
    results = {
        "gctn": {"unseen": {"success": 0.111, "ci95": [0.05, 0.2], "episodes": 72}},
        "tvf-large": {"unseen": {"success": 0.222, "ci95": [0.15, 0.3], "episodes": 72}},
    }
    return {
        "experiment": {"demos": 3, "episodes": 9, "seed_start": 1},
        "models": {"gctn": {"file": "gctn-lite.pt", "step": 77, "data_fingerprint": "abc123"}},
        "results": results,
    }


def test_quickstart_compares_gctn_and_tvf_large_beside_the_shipped_record(
    capsys, tmp_path, smoke_weights, monkeypatch
):
    weights = tmp_path / "weights"
    weights.mkdir()
    for shipped in smoke_weights.iterdir():
        if shipped.suffix != ".pt":  # the shipped form: safetensors + JSON config
            (weights / shipped.name).write_bytes(shipped.read_bytes())
    (weights / "provenance.json").write_text(json.dumps(shipped_record()))
    monkeypatch.setattr(tvf.weights, "WEIGHTS_DIR", weights)
    out_dir = tmp_path / "q"
    code, out, err = run(
        capsys, "quickstart", "--tasks", "stack-stair", "--episodes", "1", "--workers", "1",
        "--out", str(out_dir),
    )  # fmt: skip
    assert code == 0, err
    assert "the shipped weights' record on the unseen tasks: 11% vs 22%" in out
    assert "GCTN " in out and "TVF-L " in out and (out_dir / "report.html").exists()
    for method in ("gctn", "tvf-large"):
        assert (out_dir / "gifs" / method / "stack-stair-0.gif").read_bytes()[:6] == b"GIF89a"
        episodes = (out_dir / "eval" / method / "episodes.jsonl").read_text().splitlines()
        assert [json.loads(e)["seed"] for e in episodes] == [1]  # the same episode for both
    md = (out_dir / "report.md").read_text()
    assert md.startswith("# tvf quick start: GCTN vs TVF-L on stack-stair (gctn-lite + vf-lite, tvf ")
    assert "| run | GCTN and TVF-L on the same 1 episode: 1 per task on stack-stair" in md
    assert "| *shipped weights (9 episodes per task)* | 11.1% [5–20] | 22.2% [15–30] |" in md
    assert "*paper (10 demos)* | 55.4% | 78.5% |" in md
    assert "gctn-lite (step 77); tvf" in md and "data abc123, 3 demos per training task" in md
    assert "this run's episodes are the first 1 per task of them" in md
    assert "gifs/gctn/stack-stair-0.gif" in md and "gifs/tvf-large/stack-stair-0.gif" in md
    assert str(weights) not in md and "tvf experiment --" not in md


def test_quickstart_header_without_a_record():
    from tvf.experiment.quickstart import quickstart_meta
    from tvf.tasks import get_task

    meta = quickstart_meta(["gctn", "tvf-large"], [get_task("put-t")], "put-t", 5, 1, 2, 90.0, {})
    assert (
        meta["weights"].startswith("gctn-lite + vf-lite; tvf ")
        and "(no provenance record)" in meta["weights"]
    )
    assert (
        meta["run"]
        == "GCTN and TVF-L on the same 5 episodes: 5 per task on put-t, seeds 1, 3, 5, … (validation range)"
    )
    assert meta["planner"].startswith("TVF-L: K=3, depth 3, ") and "proposals" in meta["planner"]
    assert meta["shipped evaluation"] == "none recorded" and meta["wall time"] == "1.5 min with 2 workers"


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


def test_ablate_runs_every_cell_resumes_and_matches_a_plain_eval(capsys, tmp_path, smoke_weights):
    models = ("--gctn", str(smoke_weights / "gctn-lite.pt"), "--vf", str(smoke_weights / "vf-lite.pt"))
    common = ("--method", "tvf-small", *models, "--tasks", "stack-stair", "--episodes", "1")
    common += ("--seed-start", "1")
    grid = ("--k", "1,2", "--depth", "1,2", "--out", str(tmp_path / "a"))
    code, out, err = run(capsys, "ablate", *common, *grid)
    assert code == 0, err
    record = json.loads((tmp_path / "a" / "ablation.json").read_text())
    assert [(c["k"], c["depth"]) for c in record["cells"]] == [(1, 1), (1, 2), (2, 1), (2, 2)]
    for cell in record["cells"]:
        meta = json.loads((tmp_path / "a" / f"k{cell['k']}-d{cell['depth']}" / "eval.json").read_text())
        assert (meta["k"], meta["depth"]) == (cell["k"], cell["depth"])
        assert cell["groups"]["unseen"]["episodes"] == 1  # stack-stair is an unseen task
    assert (tmp_path / "a" / "ablation.png").read_bytes()[:4] == b"\x89PNG"
    assert "| 2 | " in out and "K \\ depth" in (tmp_path / "a" / "ablation.md").read_text()
    code, out, err = run(capsys, "ablate", *common, *grid)
    assert code == 0 and out.count("resuming: 1 of 1") == 4  # every cell resumed, nothing re-run
    code, _, err = run(capsys, "eval", *common, "--out", str(tmp_path / "plain"))
    assert code == 0, err
    cell = json.loads((tmp_path / "a" / "k2-d1" / "episodes.jsonl").read_text())
    plain = json.loads((tmp_path / "plain" / "episodes.jsonl").read_text())
    assert cell["actions"] == plain["actions"]  # tvf-small is the K=2, depth-1 cell


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--k", "2,x"), "--k takes comma-separated whole numbers"),
        (("--depth", "0"), "--depth needs at least one value, each at least 1"),
        (("--method", "gctn"), "--method must be one of tvf-small, tvf-large"),
        (("--turns", "3"), "--turns must be 1, 2, 4 (quarter turns"),
    ],
)
def test_ablate_refuses_a_bad_grid_in_one_line(capsys, tmp_path, args, message):
    code, _, err = run(capsys, "ablate", *args, "--out", str(tmp_path / "a"))
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "a").exists()


def test_eval_with_turns_records_them_and_refuses_them_without_a_gctn(capsys, tmp_path, smoke_weights):
    args = ("--gctn", str(smoke_weights / "gctn-lite.pt"), "--tasks", "stack-stair", "--episodes", "1")
    code, _, err = run(capsys, "eval", "--method", "gctn", "--turns", "4", *args,
                       "--out", str(tmp_path / "e"))  # fmt: skip
    assert code == 0, err
    assert json.loads((tmp_path / "e" / "eval.json").read_text())["turns"] == 4
    code, _, err = run(capsys, "eval", "--method", "gctn", *args, "--out", str(tmp_path / "e"))
    assert code == 2 and "other turns" in err  # a resume with other turns is refused, naming them
    code, _, err = run(capsys, "eval", "--method", "oracle", "--turns", "2", "--out", str(tmp_path / "o"))
    assert code == 2 and "oracle has no GCTN to symmetrise" in err


def test_eval_records_the_resolved_goal_mask_and_refuses_to_resume_an_unmasked_folder(
    capsys, tmp_path, smoke_weights
):
    args = ("--gctn", str(smoke_weights / "gctn-lite.pt"), "--tasks", "stack-stair", "--episodes", "1")
    code, _, err = run(capsys, "eval", "--method", "gctn", *args, "--out", str(tmp_path / "e"))
    assert code == 0, err
    meta_path = tmp_path / "e" / "eval.json"
    meta = json.loads(meta_path.read_text())
    assert meta["goal_mask"] is True  # the GCTN's default, resolved
    for key in ("goal_mask", "mask_places", "centre_picks", "resolved"):  # a folder from before the flags
        del meta[key]
    meta_path.write_text(json.dumps(meta))
    code, _, err = run(capsys, "eval", "--method", "gctn", *args, "--out", str(tmp_path / "e"))
    assert code == 2 and "with other centre_picks, goal_mask, mask_places" in err, err
    code, _, err = run(capsys, "eval", "--method", "gctn", "--goal-mask", "False", "--centre-picks", "False",
                       *args, "--out", str(tmp_path / "e"))  # fmt: skip
    assert code == 0, err  # the paper's unmasked GCTN resumes it
    oracle = ("eval", "--method", "oracle", "--goal-mask", "True", "--out", str(tmp_path / "o"))
    code, _, err = run(capsys, *oracle)
    assert code == 2 and "oracle has no GCTN to mask" in err


def test_eval_records_a_refined_yaw_and_resumes_only_with_it(capsys, tmp_path, smoke_weights):
    args = ("--gctn", str(smoke_weights / "gctn-lite.pt"), "--tasks", "stack-stair", "--episodes", "1")
    code, _, err = run(capsys, "eval", "--method", "gctn", *args, "--out", str(tmp_path / "e"))
    assert code == 0, err
    assert json.loads((tmp_path / "e" / "eval.json").read_text())["refine_yaw"] is True  # the default
    code, _, err = run(capsys, "eval", "--method", "gctn", "--refine-yaw", "False", *args,
                       "--out", str(tmp_path / "e"))  # fmt: skip
    assert code == 2 and "other refine_yaw" in err  # the paper's bins' turns are another evaluation


def test_eval_records_centred_picks_and_resumes_only_with_them(capsys, tmp_path, smoke_weights):
    args = ("--gctn", str(smoke_weights / "gctn-lite.pt"), "--tasks", "stack-stair", "--episodes", "1",
            "--out", str(tmp_path / "e"))  # fmt: skip
    code, _, err = run(capsys, "eval", "--method", "gctn", *args)
    assert code == 0, err
    recorded = json.loads((tmp_path / "e" / "eval.json").read_text())
    assert recorded["centre_picks"] is True and recorded["mask_places"] == "cells"  # the defaults
    code, _, err = run(capsys, "eval", "--method", "gctn", "--centre-picks", "False", *args)
    assert code == 2 and "other centre_picks" in err, err  # the GCTN's own pick pixels: another evaluation


def test_alpha_and_nms_radius_reach_the_planner_of_every_command(capsys, tmp_path, smoke_weights):
    weights = ("--gctn", str(smoke_weights / "gctn-lite.pt"), "--vf", str(smoke_weights / "vf-lite.pt"))
    roots = {}
    for alpha in ("1", "1e-9"):  # unmasked: the goal mask would leave these places fewer candidates
        code, _, err = run(
            capsys, "viz", "plan", "--task", "stack-stair", "--out", str(tmp_path / alpha), "--alpha", alpha,
            "--nms-radius", "6.4", "--k", "3", "--depth", "1", "--pick-branches", "1", "--goal-mask", "False",
            *weights,
        )  # fmt: skip
        assert code == 0, err
        roots[alpha] = len(json.loads((tmp_path / alpha / "plan.json").read_text())["nodes"])
    assert roots == {"1": 1, "1e-9": 3}  # alpha 1 keeps the best place only, 1e-9 three NMS peaks
    code, _, err = run(
        capsys, "eval", "--method", "tvf-small", "--alpha", "0.5", "--nms-radius", "6.4", *weights,
        "--tasks", "stack-stair", "--episodes", "1", "--out", str(tmp_path / "e"),
    )  # fmt: skip
    assert code == 0, err
    recorded = json.loads((tmp_path / "e" / "eval.json").read_text())
    assert recorded["alpha"] == 0.5 and recorded["nms_radius"] == 6.4
    for command in (("eval", "--method", "tvf-large"), ("ablate", "--k", "2", "--depth", "1"),
                    ("viz", "plan", "--task", "stack-stair")):  # fmt: skip
        code, _, err = run(capsys, *command, "--alpha", "0", *weights, "--out", str(tmp_path / "bad"))
        assert code == 2 and "alpha must be in (0, 1]" in err and "--alpha" in err, err
        code, _, err = run(capsys, *command, "--nms-radius", "-1", *weights, "--out", str(tmp_path / "bad"))
        assert code == 2 and "nms_radius must be a positive number" in err, err
        code, _, err = run(
            capsys, *command, "--first-step-band", "-1", *weights, "--out", str(tmp_path / "bad")
        )
        assert code == 2 and "first_step_band must be None or a score difference >= 0" in err, err
        assert "--first-step-band" in err and len(err.strip().splitlines()) == 1


def test_eval_records_the_mask_places_and_refuses_to_resume_with_another_rule(
    capsys, tmp_path, smoke_weights
):
    args = ("--gctn", str(smoke_weights / "gctn-lite.pt"), "--tasks", "stack-stair", "--episodes", "1",
            "--out", str(tmp_path / "e"))  # fmt: skip
    code, _, err = run(capsys, "eval", "--method", "gctn", "--mask-places", "ordered", *args)
    assert code == 0, err
    assert json.loads((tmp_path / "e" / "eval.json").read_text())["mask_places"] == "ordered"
    code, _, err = run(capsys, "eval", "--method", "gctn", *args)
    assert code == 2 and "other mask_places" in err  # the default rule (cells) is another evaluation
    code, _, err = run(capsys, "eval", "--method", "gctn", "--goal-mask", "False", "--mask-places", "ordered",
                       *args)  # fmt: skip
    assert code == 2 and "add --goal-mask True" in err


def test_eval_records_a_centred_share_and_root_alpha_and_resumes_only_with_them(
    capsys, tmp_path, smoke_weights
):
    weights = ("--gctn", str(smoke_weights / "gctn-lite.pt"), "--vf", str(smoke_weights / "vf-lite.pt"))
    args = (*weights, "--tasks", "stack-stair", "--episodes", "1", "--out", str(tmp_path / "e"))
    chosen = ("--mask-places", "ordered", "--centred-share", "0.75", "--root-alpha", "0.001")
    code, _, err = run(capsys, "eval", "--method", "tvf-small", *chosen, *args)
    assert code == 0, err
    recorded = json.loads((tmp_path / "e" / "eval.json").read_text())
    assert recorded["centred_share"] == 0.75 and recorded["root_alpha"] == 0.001
    assert recorded["tie_band"] == 0.002  # TVF-S's resolved default, so an older folder is not resumed
    code, _, err = run(capsys, "eval", "--method", "tvf-small", "--mask-places", "ordered", *args)
    assert code == 2 and "other centred_share, root_alpha" in err, err
    gap = ("--mask-places", "gap")  # the goal mask's every place: nothing to centre
    code, _, err = run(capsys, "eval", "--method", "tvf-small", *gap, "--centred-share", "0.75", *args)
    assert code == 2 and "--centred-share sets how the goal mask centres its places" in err, err


def test_eval_with_a_simulated_foresight_names_it_and_resumes_only_with_it(capsys, tmp_path, smoke_weights):
    args = ("--method", "tvf-small-paper", "--gctn", str(smoke_weights / "gctn-lite.pt"), "--tasks",
            "stack-stair", "--episodes", "1", "--out", str(tmp_path / "e"))  # fmt: skip
    code, out, err = run(capsys, "eval", *args, "--foresight", "simulator")
    assert code == 0, err
    assert "# Evaluation: tvf-small-paper (simulator foresight)" in out
    assert json.loads((tmp_path / "e" / "summary.json").read_text())["foresight"] == "simulator"
    assert json.loads((tmp_path / "e" / "eval.json").read_text())["resolved"]["foresight"] == "simulator"
    code, _, err = run(capsys, "eval", *args)  # the VF's search is another evaluation
    assert code == 2 and "other foresight" in err, err
    code, _, err = run(capsys, "viz", "plan", "--method", "tvf-small-paper", "--foresight", "simulator",
                       "--task", "stack-stair", "--seed", "1", "--out", str(tmp_path / "p"))  # fmt: skip
    assert code == 2 and "only tvf eval and tvf ablate run it" in err, err


def test_ablate_with_a_simulated_foresight_names_it(capsys, tmp_path, smoke_weights):
    code, out, err = run(
        capsys, "ablate", "--method", "tvf-small-paper", "--foresight", "simulator", "--gctn",
        str(smoke_weights / "gctn-lite.pt"), "--k", "1", "--depth", "1", "--tasks", "stack-stair",
        "--episodes", "1", "--out", str(tmp_path / "a"),
    )  # fmt: skip
    assert code == 0, err
    assert "# K x depth ablation (tvf-small-paper, simulator foresight)" in out
    cell = json.loads((tmp_path / "a" / "k1-d1" / "summary.json").read_text())
    assert cell["foresight"] == "simulator"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--method", "tvf-large", "--place-search", "-1"), "place_search must be 0 to 26 pixels, got -1"),
        (("--method", "tvf-large", "--turn-search", "19"), "turn_search must be 0 to 18 rotation bins"),
        (("--method", "gctn", "--place-search", "2"), "gctn does not search"),
        (("--method", "tvf-large", "--foresight", "simulator", "--turn-search", "1"), "drop them"),
    ],
)
def test_eval_refuses_a_bad_polish_in_one_line(capsys, tmp_path, args, message):
    out = str(tmp_path / "e")
    code, _, err = run(capsys, "eval", *args, "--tasks", "put-t", "--episodes", "1", "--out", out)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "e").exists()
