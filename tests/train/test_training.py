"""Training runs: run directory, checkpoints, exact resume, clear errors (smoke preset, synthetic data)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from tvf.data.format import Episode, episode_name, write_episode
from tvf.errors import TvfError
from tvf.geometry import WORKSPACE
from tvf.models.checkpoint import CheckpointError, load_checkpoint, load_trained
from tvf.runs import RunError
from tvf.train.jobs import gctn_job, vf_job
from tvf.train.trainer import TrainConfig, TrainError, check_config, learning_rate, train

TASKS = ("stack-stair", "put-t")


def synthetic_episode(task: str, seed: int, split: str, steps: int = 3) -> Episode:
    rng = np.random.default_rng(seed)
    h, w = WORKSPACE.shape
    xy = np.stack([rng.uniform(0.35, 0.65, steps), rng.uniform(-0.15, 0.15, steps)], 1)
    pick = np.concatenate([xy, np.full((steps, 1), 0.04), np.zeros((steps, 1))], 1)
    place = np.concatenate([xy[::-1], np.full((steps, 1), 0.045), rng.uniform(-0.7, 0.7, (steps, 1))], 1)
    random = np.zeros(steps, bool)
    if split == "train":
        random[0] = True
    return Episode(
        task=task, seed=seed, split=split,
        color=rng.integers(0, 256, (steps + 1, h, w, 3), dtype=np.uint8),
        height=rng.uniform(0, 0.1, (steps + 1, h, w)).astype(np.float32),
        pick=pick.astype(np.float32), place=place.astype(np.float32), random=random,
        progress=np.linspace(0, 1, steps + 1).astype(np.float32),
        blocks=np.zeros((steps + 1, 3, 4), np.float32), targets=np.zeros((3, 4), np.float32),
        attrs={"n_blocks": 3, "primitives": ["ok"] * steps},
    )  # fmt: skip


@pytest.fixture(scope="module")
def data_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("demos")
    for split, seeds in (("train", (0, 2)), ("test", (1,))):
        for task in TASKS:
            for seed in seeds:
                write_episode(root / split / task / episode_name(seed), synthetic_episode(task, seed, split))
    return root


def config(data_root, out, **kw) -> TrainConfig:
    base = TrainConfig(
        data=data_root, out=out, demos=2, preset="smoke", steps=4, batch=2, lr=1e-4, schedule="constant",
        warmup=0, tasks=",".join(TASKS),
        val_every=4, val_samples=4, checkpoint_every=2, log_every=2, progress=False,
    )  # fmt: skip
    return replace(base, **kw)


def test_gctn_run_directory_and_metrics(data_root, tmp_path):
    cfg = config(data_root, tmp_path / "run")
    val = train(cfg, gctn_job(cfg))
    run = tmp_path / "run"
    assert {"loss", "pick_acc", "place_acc"} <= set(val)
    records = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records if r["split"] == "train"] == [2, 4]
    assert {r["split"] for r in records} == {"train", "val"}
    conf = json.loads((run / "config.json").read_text())
    assert (
        conf["kind"] == "gctn" and conf["preset"]["name"] == "smoke" and len(conf["data_fingerprint"]) == 16
    )
    ckpt = load_checkpoint(run / "checkpoints" / "last.pt", "gctn")
    assert ckpt.step == 4 and (run / "checkpoints" / "step_000002.pt").exists()
    assert any((run / "tb").iterdir())


def test_resumed_run_equals_uninterrupted_run_and_redoes_no_step(data_root, tmp_path):
    full = config(data_root, tmp_path / "full")
    train(full, gctn_job(full))
    part = config(data_root, tmp_path / "part", steps=2)
    train(part, gctn_job(part))
    metrics = tmp_path / "part" / "metrics.jsonl"
    before = metrics.read_text().splitlines()
    resumed = replace(part, steps=4, resume=True)
    job = gctn_job(resumed)
    draw, batches = job.train_batch, []
    job.train_batch = lambda rng, part: batches.append(rng) or draw(rng, part)
    train(resumed, job)
    # a restart from step 0 reproduces the same weights (same seed), so count what the resume did
    assert len(batches) == 2  # steps 3 and 4 only
    after = metrics.read_text().splitlines()
    assert after[: len(before)] == before  # the first session's records are kept as they were
    steps = [(r["step"], r["split"]) for r in map(json.loads, after)]
    assert len(steps) == len(set(steps)) and [s for s, split in steps if split == "train"] == [2, 4]
    assert load_checkpoint(tmp_path / "part" / "checkpoints" / "last.pt", "gctn").step == 4
    a = load_checkpoint(tmp_path / "full" / "checkpoints" / "last.pt", "gctn").model
    b = load_checkpoint(tmp_path / "part" / "checkpoints" / "last.pt", "gctn").model
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_existing_run_needs_resume_and_matching_flags(data_root, tmp_path):
    cfg = config(data_root, tmp_path / "run", steps=2)
    train(cfg, gctn_job(cfg))
    with pytest.raises(RunError, match="--resume"):
        train(cfg, gctn_job(cfg))
    other = replace(cfg, resume=True, preset="lite")
    with pytest.raises(RunError, match="different preset"):
        train(other, gctn_job(other))


def test_vf_trains_and_checkpoint_kind_is_checked(data_root, tmp_path):
    cfg = config(data_root, tmp_path / "vf")
    val = train(cfg, vf_job(cfg))
    assert {"loss", "color_mae", "height_mae_mm"} <= set(val)
    with pytest.raises(CheckpointError, match="expected 'gctn'"):
        load_checkpoint(tmp_path / "vf" / "checkpoints" / "last.pt", "gctn")


def test_too_few_demos_is_a_clear_error(data_root, tmp_path):
    cfg = config(data_root, tmp_path / "run", demos=5)
    with pytest.raises(Exception, match="5 demos requested"):
        gctn_job(cfg)


def test_smoke_gctn_trains_then_evaluates_end_to_end(data_root, tmp_path):
    from tvf.evaluate.closed_loop import evaluate
    from tvf.policies import PolicySpec

    cfg = config(data_root, tmp_path / "run", steps=2)
    train(cfg, gctn_job(cfg))
    summary = evaluate(
        PolicySpec("gctn", gctn=str(tmp_path / "run")), ["stack-stair"], 1, 1, 1, tmp_path / "eval"
    )
    assert summary["average"]["episodes"] == 1
    episode = json.loads((tmp_path / "eval" / "episodes.jsonl").read_text().splitlines()[0])
    assert episode["steps"] == 3 and len(episode["actions"]) == 3  # the horizon of stack-stair
    assert (tmp_path / "eval" / "summary.md").exists()


def test_learning_rate_schedules():
    cfg = TrainConfig(data=".", out=".", steps=100, lr=2e-4, schedule="constant", warmup=0)
    assert [learning_rate(cfg, s) for s in (1, 50, 100)] == [2e-4] * 3
    cos = replace(cfg, schedule="cosine", warmup=10)
    assert learning_rate(cos, 5) == pytest.approx(1e-4)  # linear warm-up
    assert learning_rate(cos, 10) == pytest.approx(2e-4)  # the peak
    assert learning_rate(cos, 55) == pytest.approx(1e-4)  # half-way through the decay
    assert learning_rate(cos, 100) == pytest.approx(0.0, abs=1e-12)
    lrs = [learning_rate(cos, s) for s in range(10, 101)]
    assert all(a >= b for a, b in zip(lrs, lrs[1:], strict=False))


@pytest.mark.slow  # exact resume is tested above with the constant schedule
def test_interrupted_cosine_run_resumes_exactly_and_cannot_be_extended(data_root, tmp_path):
    full = config(data_root, tmp_path / "full", schedule="cosine", warmup=1, lr=1e-3)
    train(full, gctn_job(full))
    part = replace(full, out=tmp_path / "part")
    job = gctn_job(part)
    draw, calls = job.train_batch, []

    def interrupted(rng, part):
        calls.append(1)
        if len(calls) == 3:  # the session ends during step 3 (a checkpoint was written at step 2)
            raise KeyboardInterrupt
        return draw(rng, part)

    job.train_batch = interrupted
    with pytest.raises(KeyboardInterrupt):
        train(part, job)
    resumed = replace(part, resume=True)
    train(resumed, gctn_job(resumed))
    a = load_checkpoint(tmp_path / "full" / "checkpoints" / "last.pt", "gctn").model
    b = load_checkpoint(tmp_path / "part" / "checkpoints" / "last.pt", "gctn").model
    assert all(torch.equal(a[k], b[k]) for k in a)
    lrs = [json.loads(x).get("lr") for x in (tmp_path / "part" / "metrics.jsonl").read_text().splitlines()]
    assert lrs[-2] == 0.0  # the last logged training step ends the decay
    longer = replace(resumed, steps=8)
    with pytest.raises(RunError, match="different schedule"):
        train(longer, gctn_job(longer))


def test_bad_schedules_are_clear_errors(data_root, tmp_path):
    for bad, match in ((dict(schedule="linear"), "unknown --schedule"), (dict(warmup=4), "--warmup")):
        cfg = config(data_root, tmp_path / "bad", **{"schedule": "cosine", **bad})
        with pytest.raises(TrainError, match=match):
            train(cfg, gctn_job(cfg))


def test_changed_pixel_loss_is_recorded_resumes_only_with_itself_and_rejects_bad_weights(data_root, tmp_path):
    cfg = config(data_root, tmp_path / "vf", steps=2, vf_changed_weight=20.0)
    plain = config(data_root, tmp_path / "plain", steps=2)
    train(cfg, vf_job(cfg))
    train(plain, vf_job(plain))
    saved = json.loads((tmp_path / "vf" / "config.json").read_text())
    assert saved["loss"] == {"changed_weight": 20.0}
    assert "loss" not in json.loads((tmp_path / "plain" / "config.json").read_text())
    batch = vf_job(cfg).train_batch(np.random.default_rng(0), None)
    weighted, reference = vf_job(cfg).loss(batch)[0], vf_job(plain).loss(batch)[0]
    assert weighted > reference  # the same model and batch: the changed pixels count 21 times
    other = replace(cfg, resume=True, vf_changed_weight=5.0, steps=3)
    with pytest.raises(RunError, match="loss"):
        train(other, vf_job(other))
    for bad in (-1.0, float("nan")):
        with pytest.raises(TrainError, match="--vf-changed-weight"):
            train(replace(cfg, vf_changed_weight=bad), vf_job(cfg))


def test_rollout_loss_is_recorded_resumes_only_with_itself_and_is_refused_elsewhere(data_root, tmp_path):
    cfg = config(data_root, tmp_path / "vf", steps=2, vf_rollout=2, vf_changed_weight=20.0)
    train(cfg, vf_job(cfg))
    saved = json.loads((tmp_path / "vf" / "config.json").read_text())
    assert saved["loss"] == {"changed_weight": 20.0, "rollout": 2}
    job = vf_job(cfg)
    batch = job.train_batch(np.random.default_rng(0), None)
    assert batch["picks"].shape == (2, 2, 2)  # the training batches are two-step rollouts
    one_step = vf_job(replace(cfg, vf_rollout=1)).loss(batch)[0]
    assert not torch.isclose(job.loss(batch)[0], one_step)  # the second step counts
    other = replace(cfg, resume=True, vf_rollout=3, steps=3)
    with pytest.raises(RunError, match="loss"):
        train(other, vf_job(other))
    with pytest.raises(TrainError, match="--vf-rollout"):
        train(replace(cfg, vf_rollout=0), vf_job(cfg))
    gctn = config(data_root, tmp_path / "gctn", vf_rollout=2)
    with pytest.raises(TrainError, match="--vf-rollout is a VF flag"):
        gctn_job(gctn)
    # a fine-tune may start from these weights with another head (the same network's output, read locally)
    tuned = config(
        data_root, tmp_path / "tuned", steps=2, vf_rollout=2, vf_head="local", init=tmp_path / "vf"
    )
    train(tuned, vf_job(tuned))
    assert json.loads((tmp_path / "tuned" / "config.json").read_text())["init"]["step"] == 2


@pytest.mark.slow  # make test-all
def test_symmetrised_training_starts_from_given_weights_and_is_recorded(data_root, tmp_path):
    base = config(data_root, tmp_path / "base", steps=2)
    train(base, gctn_job(base))
    tuned = config(data_root, tmp_path / "tuned", steps=2, turns=2, init=tmp_path / "base",
                   val_samples=2)  # fmt: skip
    job = gctn_job(tuned)
    start = load_checkpoint(tmp_path / "base" / "checkpoints" / "last.pt", "gctn").model
    assert all(torch.equal(job.model.state_dict()[k], start[k]) for k in start)  # --init loaded them
    batch = job.train_batch(np.random.default_rng(0), None)
    symmetrised, plain = job.loss(batch)[0], gctn_job(replace(tuned, turns=1)).loss(batch)[0]
    assert not torch.isclose(symmetrised, plain)  # the same weights and batch, the averaged maps' loss
    val = train(tuned, job)
    saved = json.loads((tmp_path / "tuned" / "config.json").read_text())
    assert saved["turns"] == 2 and saved["init"]["step"] == 2 and len(saved["init"]["sha256"]) == 64
    assert "turns" not in json.loads((tmp_path / "base" / "config.json").read_text())
    assert {"loss", "pick_acc", "place_acc"} <= set(val)
    assert load_checkpoint(tmp_path / "tuned" / "checkpoints" / "last.pt", "gctn").step == 2  # a plain GCTN
    with pytest.raises(TvfError, match="--turns must be 1, 2 or 4"):
        gctn_job(replace(tuned, out=tmp_path / "zero", turns=0))
    train(
        replace(base, resume=True, steps=4), gctn_job(replace(base, resume=True, steps=4))
    )  # --init moved on
    longer = replace(tuned, resume=True, steps=3)
    train(longer, gctn_job(longer))  # resumes from its own checkpoint, recording the weights it began with
    assert json.loads((tmp_path / "tuned" / "config.json").read_text())["init"] == saved["init"]
    assert load_checkpoint(tmp_path / "tuned" / "checkpoints" / "last.pt", "gctn").step == 3
    other = replace(tuned, resume=True, turns=4, steps=4)
    with pytest.raises(RunError, match="turns"):
        train(other, gctn_job(other))
    with pytest.raises(RunError, match="does not exist"):
        gctn_job(replace(tuned, out=tmp_path / "new", init=tmp_path / "nowhere.pt"))
    with pytest.raises(TrainError, match="--turns is a GCTN flag"):
        vf_job(replace(tuned, out=tmp_path / "vf"))
    with pytest.raises(CheckpointError, match="expected 'gctn'"):
        vf = config(data_root, tmp_path / "vf", steps=2)
        train(vf, vf_job(vf))
        gctn_job(replace(tuned, out=tmp_path / "again", init=tmp_path / "vf"))


def test_c4_kernels_are_a_gctn_flag_recorded_in_the_preset(data_root, tmp_path):
    cfg = config(data_root, tmp_path / "c4", steps=2, gctn_kernels="c4")
    train(cfg, gctn_job(cfg))
    saved = json.loads((tmp_path / "c4" / "config.json").read_text())
    assert saved["preset"]["gctn_kernels"] == "c4"
    checkpoint = load_checkpoint(tmp_path / "c4" / "checkpoints" / "last.pt", "gctn")
    assert checkpoint.config["preset"] == saved["preset"]
    plain = replace(cfg, resume=True, steps=3, gctn_kernels=None)
    with pytest.raises(RunError, match="preset"):  # another network: a resume must name the same kernels
        train(plain, gctn_job(plain))
    with pytest.raises(TrainError, match="--gctn-kernels is a GCTN flag"):
        vf_job(replace(cfg, out=tmp_path / "vf"))
    with pytest.raises(TvfError, match="gctn_kernels must be one of plain, c4"):
        gctn_job(replace(cfg, out=tmp_path / "bad", gctn_kernels="c8"))


def test_gctn_width_is_a_gctn_flag_recorded_in_the_preset(data_root, tmp_path):
    cfg = config(data_root, tmp_path / "wide", steps=2, gctn_width=0.125)
    train(cfg, gctn_job(cfg))
    saved = json.loads((tmp_path / "wide" / "config.json").read_text())
    assert (saved["preset"]["attention_width"], saved["preset"]["transport_width"]) == (0.125, 0.125)
    assert saved["preset"]["vf_width"] == 0.0625  # the VF's width stays the preset's
    narrow = config(data_root, tmp_path / "narrow", steps=2)
    train(narrow, gctn_job(narrow))

    def count(run: str) -> int:  # the parameters of the GCTN the planners build from a run
        return sum(p.numel() for p in load_trained(tmp_path / run, "gctn").parameters())

    assert count("wide") > 3 * count("narrow")
    again = replace(cfg, resume=True, steps=3, gctn_width=None)
    with pytest.raises(RunError, match="preset"):  # another network: a resume must name the same width
        train(again, gctn_job(again))
    with pytest.raises(TrainError, match="--gctn-width is a GCTN flag"):
        vf_job(replace(cfg, out=tmp_path / "vf"))
    for bad in (0.0, -1.0, 3.0, float("nan")):
        with pytest.raises(TrainError, match="--gctn-width must be between 0.03 and 2"):
            gctn_job(replace(cfg, out=tmp_path / "bad", gctn_width=bad))
    assert not (tmp_path / "bad").exists()


def check_gctn_sample_flag(data_root, tmp_path, flag: str, value: float, other: float) -> None:
    """A GCTN flag of how samples are drawn: recorded in the run's config when set (absent when 0), a
    resume with another value refused, the VF refusing it, shares outside 0-1 (NaN too) refused."""
    cfg = config(data_root, tmp_path / flag, steps=2, **{flag: value})
    train(cfg, gctn_job(cfg))
    assert json.loads((tmp_path / flag / "config.json").read_text())[flag] == value
    plain = config(data_root, tmp_path / "plain", steps=2)
    train(plain, gctn_job(plain))
    assert flag not in json.loads((tmp_path / "plain" / "config.json").read_text())
    changed = replace(plain, resume=True, steps=3, **{flag: other})
    with pytest.raises(RunError, match=flag):  # a resume must draw its samples as the run did
        train(changed, gctn_job(changed))
    with pytest.raises(TrainError, match=f"--{flag} is a GCTN flag"):
        vf_job(replace(cfg, out=tmp_path / "vf"))
    for bad in (1.5, -0.1, float("nan")):
        with pytest.raises(TrainError, match=f"--{flag} .*between 0 and 1"):
            check_config(replace(cfg, out=tmp_path / "bad", **{flag: bad}))
    assert not (tmp_path / "bad").exists()


def test_mirror_images_are_a_gctn_flag_recorded_and_matched_on_resume(data_root, tmp_path):
    mirrored = gctn_job(config(data_root, tmp_path / "m", steps=2, mirror=1.0))
    assert all(mirrored.train_batch(np.random.default_rng(k), None)["aug_mirror"].all() for k in range(3))
    plain = gctn_job(config(data_root, tmp_path / "p", steps=2))
    assert not plain.train_batch(np.random.default_rng(0), None)["aug_mirror"].any()
    check_gctn_sample_flag(data_root, tmp_path, "mirror", 1.0, 0.5)


def test_hindsight_goals_are_a_gctn_flag_recorded_and_matched_on_resume(data_root, tmp_path):
    job = gctn_job(config(data_root, tmp_path / "h", steps=2, hindsight=0.5))
    batches = [job.train_batch(np.random.default_rng(k), None) for k in range(8)]
    frames = torch.cat([b["goal_frame"] for b in batches])
    steps = torch.cat([b["step"] for b in batches])
    assert (frames > steps).all()
    check_gctn_sample_flag(data_root, tmp_path, "hindsight", 0.5, 0.25)
