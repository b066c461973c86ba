"""`tvf experiment` end to end with the smoke preset: every stage, resume, and a changed-config refusal."""

import json

import pytest

from tvf.errors import TvfError
from tvf.experiment.config import ExperimentConfig
from tvf.experiment.pipeline import check_experiment, run_experiment, ship_weights, train_config
from tvf.experiment.shipping import model_card
from tvf.io import read_jsonl
from tvf.models.checkpoint import load_model
from tvf.weights import sha256_file, shipped_files


@pytest.fixture(scope="module")
def experiment(tmp_path_factory):
    cfg = ExperimentConfig(
        out=tmp_path_factory.mktemp("exp"), demos=1, preset="smoke", test_demos=1, train_tasks="stack-tower",
        tasks="stack-stair", methods="gctn,tvf-large", episodes=1, workers=1,
    )  # fmt: skip
    return cfg, run_experiment(cfg)


def test_every_stage_writes_its_outputs(experiment):
    cfg, report = experiment
    out = cfg.out
    assert report == out / "report.md" and report.exists() and (out / "report.html").exists()
    assert (out / "success.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for method, column in (("gctn", "GCTN"), ("tvf-large", "TVF-L")):
        summary = json.loads((out / "eval" / method / "summary.json").read_text())
        assert summary["method"] == method and summary["average"]["episodes"] == 1
        assert column in report.read_text()
    assert (out / "eval-vf" / "metrics.json").exists()
    assert (out / "gifs" / "stack-stair-0.gif").read_bytes()[:6] == b"GIF89a"
    assert "gifs/stack-stair-0.gif" in report.read_text()
    provenance = json.loads((out / "weights" / "provenance.json").read_text())
    assert provenance["models"]["gctn"]["step"] == 2 and provenance["models"]["vf"]["step"] == 2
    assert provenance["experiment"]["preset"] == "smoke"
    assert set(provenance["results"]) == {"gctn", "tvf-large"}
    assert provenance["results"]["gctn"]["unseen"]["episodes"] == 1
    assert [r["task"] for r in provenance["task_results"]["tvf-large"]] == ["stack-stair"]  # per task too
    assert report.read_text().startswith("# tvf experiment: smoke models, 1 demo per training task")
    model, ckpt = load_model(out / "weights" / "gctn-smoke.safetensors", "gctn")  # named after its preset
    assert ckpt.optimizer is None and ckpt.step == 2
    assert provenance["models"]["vf"]["sha256"]["vf-smoke.safetensors"] == sha256_file(
        out / "weights" / "vf-smoke.safetensors"
    )
    assert (out / "weights" / "README.md").read_text() == model_card(provenance)
    assert "TVF-L (the experiment) | test (odd, from 1 000 001) | 1 |" in model_card(provenance)
    stages = [r["stage"] for r in read_jsonl(out / "cost.jsonl")]  # every stage's cost, in order
    assert stages == ["data", "train", "eval-vf", "eval", "gifs", "report", "weights"]
    assert "| cost so far | " in report.read_text() and "train " in report.read_text()  # those before it


def test_ship_copies_the_weights_folder_into_the_package(experiment, tmp_path):
    cfg, _ = experiment
    ship_weights(cfg.out / "weights", tmp_path, "smoke")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(shipped_files("smoke"))
    load_model(tmp_path / "vf-smoke.safetensors", "vf")


def test_rerun_resumes_without_redoing_work(experiment):
    cfg, report = experiment
    episodes = (cfg.out / "eval" / "tvf-large" / "episodes.jsonl").read_text()
    gif = (cfg.out / "gifs" / "stack-stair-0.gif").stat().st_mtime_ns
    run_experiment(cfg)
    assert (cfg.out / "eval" / "tvf-large" / "episodes.jsonl").read_text() == episodes
    assert (cfg.out / "gifs" / "stack-stair-0.gif").stat().st_mtime_ns == gif
    commands = json.loads((cfg.out / "experiment.json").read_text())["commands"]
    assert len(commands) == 2


def test_a_foresight_variant_adds_its_own_evaluation_and_column(experiment):
    cfg, _ = experiment
    variant = ExperimentConfig(**{**cfg.__dict__, "methods": "tvf-large+rigid", "stages": "eval,report"})
    report = run_experiment(variant).read_text()
    summary = json.loads((cfg.out / "eval" / "tvf-large+rigid" / "summary.json").read_text())
    assert summary["method"] == "tvf-large" and summary["foresight"] == "rigid"
    assert summary["average"]["episodes"] == 1
    header = next(line for line in report.splitlines() if line.startswith("| task |"))
    assert header.index("| TVF-L |") < header.index("| TVF-L, rigid foresight |")  # beside its method
    recorded = json.loads((cfg.out / "experiment.json").read_text())
    assert recorded["methods"] == "gctn,tvf-large,tvf-large+rigid"


def test_other_settings_in_the_same_folder_are_refused(experiment):
    cfg, _ = experiment
    other = ExperimentConfig(**{**cfg.__dict__, "episodes": 3, "stages": "report"})
    with pytest.raises(TvfError, match="other episodes"):
        run_experiment(other)


def test_bad_stage_method_and_preset_are_one_line_errors(tmp_path):
    with pytest.raises(TvfError, match="unknown stage"):
        run_experiment(ExperimentConfig(out=tmp_path, stages="data,fly"))
    with pytest.raises(TvfError, match="unknown method"):
        run_experiment(ExperimentConfig(out=tmp_path, methods="gctn,magic"))
    with pytest.raises(TvfError, match="gctn does not search, so it takes no foresight"):
        run_experiment(ExperimentConfig(out=tmp_path, methods="gctn+rigid"))
    with pytest.raises(TvfError, match="--methods names no method"):
        run_experiment(ExperimentConfig(out=tmp_path, methods=" , "))
    with pytest.raises(TvfError, match="unknown preset"):
        run_experiment(ExperimentConfig(out=tmp_path, preset="huge"))
    with pytest.raises(TvfError, match="missing"):
        ship_weights(tmp_path, tmp_path / "target")


def test_corrupt_experiment_record_is_a_one_line_error(tmp_path):
    (tmp_path / "experiment.json").write_text('{"demos": 10,')
    with pytest.raises(TvfError, match="not valid JSON"):
        run_experiment(ExperimentConfig(out=tmp_path, stages="report"))
    assert (tmp_path / "experiment.json").read_text() == '{"demos": 10,'  # nothing overwritten


def test_training_defaults_come_from_the_preset_and_flags_win(tmp_path):
    lite = ExperimentConfig(out=tmp_path, preset="lite").resolved()
    gctn = train_config(lite, "gctn")
    assert (gctn.steps, gctn.batch, gctn.schedule, gctn.warmup) == (21000, 2, "cosine", 500)
    assert train_config(lite, "vf").schedule == "constant"
    mine = ExperimentConfig(out=tmp_path, preset="lite", gctn_steps=10, gctn_schedule="constant").resolved()
    assert (mine.gctn_steps, mine.gctn_schedule, mine.gctn_batch) == (10, "constant", 2)
    c4 = ExperimentConfig(out=tmp_path, preset="lite", gctn_kernels="c4").resolved()
    assert (train_config(c4, "gctn").gctn_kernels, train_config(c4, "vf").gctn_kernels) == ("c4", None)
    assert train_config(lite, "gctn").gctn_kernels is None  # the preset's plain kernels
    wide = ExperimentConfig(out=tmp_path, preset="lite", gctn_width=0.25).resolved()
    assert (train_config(wide, "gctn").gctn_width, train_config(wide, "vf").gctn_width) == (0.25, None)
    assert train_config(lite, "gctn").gctn_width is None  # the preset's width
    hindsight = ExperimentConfig(out=tmp_path, preset="lite", gctn_hindsight=0.5).resolved()
    assert (train_config(hindsight, "gctn").hindsight, train_config(hindsight, "vf").hindsight) == (0.5, 0.0)
    assert train_config(lite, "gctn").hindsight == 0.0  # the paper's: every goal the last frame
    mirror = ExperimentConfig(out=tmp_path, preset="lite", gctn_mirror=0.5).resolved()
    assert (train_config(mirror, "gctn").mirror, train_config(mirror, "vf").mirror) == (0.5, 0.0)
    assert train_config(lite, "gctn").mirror == 0.0  # the paper's: no mirror images
    with pytest.raises(TvfError, match="gctn training: --hindsight 1.5: a share"):
        check_experiment(ExperimentConfig(out=tmp_path / "bad", preset="lite", gctn_hindsight=1.5))
    assert not (tmp_path / "bad").exists()


@pytest.mark.slow  # make test-all
def test_changed_data_is_named_and_restart_retrains_and_reevaluates(experiment, tmp_path):
    import shutil
    from dataclasses import replace

    from tvf.data.format import read_episode, write_episode
    from tvf.errors import StaleError

    cfg, _ = experiment
    copy = replace(cfg, out=tmp_path / "exp")
    shutil.copytree(cfg.out, copy.out)
    episode = next((copy.data_root / "train" / "stack-tower").glob("*.h5"))
    changed = read_episode(episode)
    changed.height[:] += 0.001  # re-rendered a millimetre higher (every frame: every batch sees it)
    episode.unlink()
    write_episode(episode, changed)
    with pytest.raises(StaleError, match=f"train:stack-tower/{changed.seed}"):
        run_experiment(replace(copy, stages="train"))
    before = (copy.out / "eval" / "gctn" / "eval.json").read_text()
    run_experiment(replace(copy, stages="train,eval", restart=True))
    after = json.loads((copy.out / "eval" / "gctn" / "eval.json").read_text())
    assert after["weights"]["gctn"] != json.loads(before)["weights"]["gctn"]  # evaluated with the new weights
    assert after["weights"]["gctn"] == sha256_file(copy.out / "gctn" / "checkpoints" / "last.pt")


def test_vf_tune_fine_tunes_the_vf_and_every_later_stage_uses_it(tmp_path):
    from tvf.experiment.pipeline import model_dir, tune_config
    from tvf.train.registry import VF_TUNES

    cfg = ExperimentConfig(
        out=tmp_path, demos=1, preset="smoke", test_demos=1, train_tasks="stack-tower", tasks="stack-stair",
        methods="gctn", episodes=1, workers=1, gifs=0, vf_tune=True, stages="data,train,eval-vf,weights",
    )  # fmt: skip
    run_experiment(cfg)
    tuned = json.loads((tmp_path / "vf-tuned" / "config.json").read_text())
    phase, head = VF_TUNES["smoke"]
    assert tuned["init"]["sha256"] == sha256_file(tmp_path / "vf" / "checkpoints" / "last.pt")  # from EXP/vf
    assert tuned["preset"]["vf_head"] == head
    assert tuned["loss"]["rollout"] == phase.vf_rollout and tuned["loss"]["changed_weight"] == 20.0
    assert tune_config(cfg.resolved()).init == tmp_path / "vf"
    assert model_dir(cfg, "vf") == tmp_path / "vf-tuned" and model_dir(cfg, "gctn") == tmp_path / "gctn"
    shipped = json.loads((tmp_path / "weights" / "provenance.json").read_text())["models"]["vf"]["train"]
    assert shipped["out"] == str(tmp_path / "vf-tuned") and shipped["init"] == str(tmp_path / "vf")
    card = (tmp_path / "weights" / "README.md").read_text()  # the card names the weights it started from
    assert (
        f"* vf: trained from the weights `{tmp_path / 'vf'}` (step 2, SHA-256 `{tuned['init']['sha256']}`)"
        in card
    )
    assert (
        "with --vf-head local --vf-changed-weight 20 --vf-rollout 2." in card
        and "* gctn: trained" not in card
    )
    assert json.loads((tmp_path / "eval-vf" / "metrics.json").read_text())
    with pytest.raises(TvfError, match="no fine-tuning recipe for preset 'paper'"):
        run_experiment(ExperimentConfig(out=tmp_path / "p", preset="paper", vf_tune=True))
    with pytest.raises(TvfError, match="other vf_tune"):  # a folder's VF phases are part of the experiment
        run_experiment(ExperimentConfig(**{**cfg.__dict__, "vf_tune": False, "stages": "report"}))
