"""`tvf train latent`: the latent-dynamics baseline trains like the VF, records its loss and resumes."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from cli_run import run
from data_factory import make_episode

from tvf.data import write_episode
from tvf.data.format import episode_name
from tvf.models.checkpoint import CheckpointError, load_checkpoint
from tvf.models.presets import LATENT_PRESETS
from tvf.runs import RunError
from tvf.train.jobs import latent_job
from tvf.train.trainer import TrainConfig, TrainError, train

TASKS = ("stack-stair", "put-t")


@pytest.fixture(scope="module")
def data_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("demos")
    for split, seeds in (("train", (0, 2)), ("test", (1,))):
        for i, task in enumerate(TASKS):
            for seed in seeds:
                ep = make_episode(task, seed=seed, steps=2, split=split, rng_seed=10 * i + seed)
                write_episode(root / split / task / episode_name(seed), ep)
    return root


def config(data_root, out, **kw) -> TrainConfig:
    base = TrainConfig(
        data=data_root, out=out, demos=2, preset="smoke", steps=2, batch=2, lr=1e-4, schedule="constant",
        warmup=0, tasks=",".join(TASKS), val_every=2, val_samples=2, checkpoint_every=1, log_every=1,
        progress=False,
    )  # fmt: skip
    return replace(base, **kw)


def test_latent_trains_records_its_loss_and_resumes_only_with_the_same_loss(data_root, tmp_path):
    cfg = config(data_root, tmp_path / "run")
    val = train(cfg, latent_job(cfg))
    assert {"loss", "recon", "latent", "color_mae", "height_mae_mm"} <= set(val)
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    assert saved["kind"] == "latent" and saved["loss"] == {"recon_weight": 1.0, "latent_weight": 1.0}
    assert saved["latent"] == LATENT_PRESETS["smoke"].as_dict()
    records = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    train_records = [r for r in records if r["split"] == "train"]
    assert [r["step"] for r in train_records] == [1, 2]
    assert all({"loss", "next", "recon", "latent"} <= set(r) for r in train_records)
    last = tmp_path / "run" / "checkpoints" / "last.pt"
    assert load_checkpoint(last, "latent").step == 2
    with pytest.raises(CheckpointError, match="holds a 'latent' model, expected 'vf'"):
        load_checkpoint(last, "vf")
    # a resume continues from step 2 (the same weights as training 3 steps at once)
    more = replace(cfg, steps=3, resume=True)
    train(more, latent_job(more))
    assert load_checkpoint(last, "latent").step == 3
    weighted = replace(more, steps=4, vf_changed_weight=20.0)
    with pytest.raises(RunError, match="loss"):
        train(weighted, latent_job(weighted))
    batch = latent_job(cfg).train_batch(np.random.default_rng(0))
    heavier = latent_job(replace(cfg, vf_changed_weight=20.0)).loss(batch)[0]
    assert heavier > latent_job(cfg).loss(batch)[0]  # the changed pixels of the next image count 21 times
    with pytest.raises(TrainError, match="--vf-head is a VF flag"):
        latent_job(replace(cfg, vf_head="blend"))


def test_resumed_latent_run_equals_an_uninterrupted_one(data_root, tmp_path):
    full = config(data_root, tmp_path / "full", steps=2)
    train(full, latent_job(full))
    part = config(data_root, tmp_path / "part", steps=1)
    train(part, latent_job(part))
    resumed = replace(part, steps=2, resume=True)
    train(resumed, latent_job(resumed))
    a = load_checkpoint(tmp_path / "full" / "checkpoints" / "last.pt", "latent").model
    b = load_checkpoint(tmp_path / "part" / "checkpoints" / "last.pt", "latent").model
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_cli_train_latent(data_root, tmp_path, capsys):
    def args(out, *more):
        return ("train", "latent", "--data", str(data_root), "--out", str(out), "--preset", "smoke",
                "--demos", "2", "--tasks", ",".join(TASKS), "--steps", "1", "--batch", "1", "--no-progress",
                *more)  # fmt: skip

    out = tmp_path / "cli"
    code, stdout, err = run(capsys, *args(out))
    assert code == 0, err
    assert "done:" in stdout and (out / "checkpoints" / "last.pt").exists()
    assert json.loads((out / "config.json").read_text())["kind"] == "latent"
    again = ("--config", str(out / "config.json"), "--out", str(tmp_path / "again"))
    code, _, err = run(capsys, "train", "latent", *again)
    assert code == 0, err  # relaunched from its saved flags
    code, _, err = run(capsys, *args(tmp_path / "head", "--vf-head", "local"))
    assert code == 2 and err.strip().count("\n") == 0 and "--vf-head is a VF flag" in err
