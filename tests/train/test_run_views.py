"""Runs you can look at and relaunch: validation pictures in TensorBoard, optional W&B logging (offline),
and `tvf train --config RUN/config.json` (smoke preset, synthetic data, a few steps)."""

from __future__ import annotations

import io
import json
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_run import run
from data_factory import make_episode
from PIL import Image
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from tvf.cli import main
from tvf.data.format import episode_name, write_episode
from tvf.data.samplers import GctnSampler, VfSampler
from tvf.models.checkpoint import load_checkpoint
from tvf.models.gctn import GCTN, argmax_pixels
from tvf.models.images import to_rgbh
from tvf.models.presets import get_preset
from tvf.models.vf import VisualForesight
from tvf.train.jobs import gctn_job, vf_job
from tvf.train.pictures import SCALE, heat_overlay, vf_pictures
from tvf.train.pictures import gctn_pictures as draw_gctn
from tvf.train.trainer import TrainConfig, TrainError, train

GREEN, RED = (0, 255, 0), (255, 0, 0)


@pytest.fixture(scope="module")
def data_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("demos")
    for split, seeds in (("train", (0, 2)), ("test", (1,))):
        for seed in seeds:
            episode = make_episode("stack-stair", seed, steps=3, split=split, rng_seed=seed)
            write_episode(root / split / "stack-stair" / episode_name(seed), episode)
    return root


def cli_flags(data_root: Path, out: Path) -> list[str]:
    return ["--data", str(data_root), "--demos", "2", "--preset", "smoke", "--steps", "4", "--batch", "2",
            "--tasks", "stack-stair", "--val-every", "2", "--val-samples", "4", "--checkpoint-every", "2",
            "--log-every", "2", "--no-progress", "--out", str(out)]  # fmt: skip


@pytest.fixture(scope="module")
def gctn_run(data_root, tmp_path_factory) -> Path:
    """A 4-step GCTN run made by the CLI (validation at steps 2 and 4)."""
    out = tmp_path_factory.mktemp("runs") / "gctn"
    main(["train", "gctn", *cli_flags(data_root, out)])
    return out


def config(data_root: Path, out: Path, **kw) -> TrainConfig:
    base = TrainConfig(
        data=data_root, out=out, demos=2, preset="smoke", steps=4, batch=2, lr=1e-3, schedule="constant",
        warmup=0, tasks="stack-stair", val_every=1, val_samples=4, checkpoint_every=4, log_every=2,
        progress=False,
    )  # fmt: skip
    return replace(base, **kw)


def tb_images(run: Path) -> dict[str, list[tuple[int, np.ndarray]]]:
    """The image summaries of RUN/tb: tag -> [(step, decoded RGB array)]."""
    acc = EventAccumulator(str(run / "tb"), size_guidance={"images": 0})
    acc.Reload()
    return {
        tag: [(e.step, np.asarray(Image.open(io.BytesIO(e.encoded_image_string)))) for e in acc.Images(tag)]
        for tag in acc.Tags()["images"]
    }


def has_colour(image: np.ndarray, rgb: tuple[int, int, int]) -> bool:
    return bool((image[..., :3] == rgb).all(-1).any())


# --- TensorBoard pictures -------------------------------------------------------------------------------


def test_gctn_validation_writes_heat_maps_to_tensorboard(gctn_run):
    images = tb_images(gctn_run)
    assert list(images) == ["images/heatmaps"]
    assert [step for step, _ in images["images/heatmaps"]] == [2, 4]  # every validation
    for _, image in images["images/heatmaps"]:
        assert image.shape[:2] == (160 * SCALE, (3 * 160 + 2 * 4) * SCALE)  # pick | place | goal
        assert has_colour(image, GREEN) and has_colour(image, RED)  # the label and the argmax


def test_vf_pictures_every_second_validation_or_never(data_root, tmp_path):
    cfg = config(data_root, tmp_path / "vf", images_every=2)
    train(cfg, vf_job(cfg))
    images = tb_images(tmp_path / "vf")
    assert [step for step, _ in images["images/foresight"]] == [2, 4]  # of the validations at 1, 2, 3, 4
    assert images["images/foresight"][0][1].shape[:2] == ((2 * 160 + 4) * SCALE, (3 * 160 + 2 * 4) * SCALE)
    none = config(data_root, tmp_path / "none", steps=2, images_every=0)
    train(none, gctn_job(none))
    assert tb_images(tmp_path / "none") == {}
    bad = config(data_root, tmp_path / "bad", images_every=-1)
    with pytest.raises(TrainError, match="--images-every"):
        train(bad, gctn_job(bad))


def test_heat_overlay_keeps_the_scene_where_the_map_is_lowest():
    color = np.full((8, 8, 3), 100, np.uint8)
    weights = np.zeros((8, 8))
    weights[2, 5] = 3.0
    out = heat_overlay(color, weights)
    assert (out[weights == 0] == 100).all()  # transparent at the minimum
    assert not (out[2, 5] == 100).all()  # the maximum shows the top colour of the map


def test_gctn_pictures_mark_the_label_and_the_argmax(data_root):
    model = GCTN(get_preset("smoke"), seed=3).eval()
    episode = make_episode("stack-stair", 1, steps=3, split="test", rng_seed=1)
    item = GctnSampler([episode], augment=False, n_rotations=model.preset.n_rotations).item(1)
    image = draw_gctn(model, item, torch.device("cpu"))["heatmaps"]
    current = to_rgbh(item["current_color"], item["current_height"])
    goal = to_rgbh(item["goal_color"], item["goal_height"])
    r, c = (int(v) * SCALE for v in argmax_pixels(model.pick_logits(current, goal))[0])
    assert tuple(image[r, c]) == RED  # the cross sits on the pick map's argmax
    lr, lc = (int(v) for v in item["pick"][0])
    border = [((lr + dr) * SCALE, (lc + dc) * SCALE) for dr in (-6, 6) for dc in range(-6, 7)]
    green = [tuple(image[y, x]) == GREEN for y, x in border if 0 <= y < image.shape[0] and 0 <= x < 320]
    assert np.mean(green) > 0.5  # the label's square (where the cross does not cover it)
    goal_panel = image[:, 2 * (2 * 160 + 2 * 4) :]
    assert np.array_equal(goal_panel[::SCALE, ::SCALE], item["goal_color"][0].numpy().astype(np.uint8))


def test_vf_pictures_show_input_prediction_and_truth():
    model = VisualForesight(get_preset("smoke"), seed=3).eval()
    episode = make_episode("stack-stair", 1, steps=3, split="test", rng_seed=1)
    item = VfSampler([episode], augment=False, n_rotations=36, identity_fraction=0.0).item(1)
    image = vf_pictures(model, item, torch.device("cpu"))["foresight"][::SCALE, ::SCALE]
    column = lambda i: slice(i * (160 + 4), i * (160 + 4) + 160)  # noqa: E731
    truth = item["next_color"][0].numpy().astype(np.uint8)
    assert np.array_equal(image[:160, column(2)], truth)
    color, _ = model.predict(item["current_color"], item["current_height"], item["pick"], item["place"],
                             item["yaw"])  # fmt: skip
    assert np.abs(image[:160, column(1)].astype(int) - color[0].numpy()).max() <= 1
    assert not np.array_equal(image[160 + 4 :, column(1)], image[160 + 4 :, column(2)])  # height row


# --- Weights & Biases -----------------------------------------------------------------------------------


def wandb_records(path: Path) -> list:
    """The protobuf records of an offline W&B run file (a LevelDB-style log after a 7-byte header)."""
    from wandb.proto import wandb_internal_pb2

    data = path.read_bytes()
    assert data[:4] == b":W&B"
    pos, block, out, part = 7, 32768, [], b""
    while pos + 7 <= len(data):
        left = block - pos % block
        if left < 7:  # a block's tail too short for a chunk header is padding
            pos += left
            continue
        length, kind = int.from_bytes(data[pos + 4 : pos + 6], "little"), data[pos + 6]
        part += data[pos + 7 : pos + 7 + length]
        pos += 7 + length
        if kind in (1, 4):  # a full record, or the last chunk of one
            record = wandb_internal_pb2.Record()
            record.ParseFromString(part)
            out.append(record)
            part = b""
    return out


def finished_wandb_records(path: Path, timeout: float = 120.0) -> list:
    """The records once W&B's service has written the run's exit record (it writes after finish())."""
    deadline = time.monotonic() + timeout
    while True:
        found = wandb_records(path)
        if any(r.WhichOneof("record_type") == "exit" for r in found) or time.monotonic() > deadline:
            return found
        time.sleep(0.5)


@pytest.mark.slow  # wandb's offline service starts: about 12 s
def test_wandb_offline_gets_the_scalars_and_the_images(data_root, tmp_path, monkeypatch):
    pytest.importorskip("wandb")
    for var, value in (("WANDB_MODE", "offline"), ("WANDB_SILENT", "true"), ("WANDB_CONSOLE", "off")):
        monkeypatch.setenv(var, value)
    for var in ("WANDB_CONFIG_DIR", "WANDB_CACHE_DIR", "WANDB_DATA_DIR", "WANDB_ARTIFACT_DIR"):
        monkeypatch.setenv(var, str(tmp_path / "wandb-home"))
    cfg = config(data_root, tmp_path / "run", val_every=2, wandb=True)
    train(cfg, gctn_job(cfg))
    (run_file,) = (tmp_path / "run" / "wandb").glob("offline-run-*/run-*.wandb")
    rows = {}
    for record in finished_wandb_records(run_file):
        if record.WhichOneof("record_type") == "history":
            items = {i.key or "/".join(i.nested_key): json.loads(i.value_json) for i in record.history.item}
            rows[items["_step"]] = items
    metrics = [json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert sorted(rows) == [2, 4]
    for m in metrics:
        for key, value in m.items():
            if key not in ("step", "split"):
                assert rows[m["step"]][f"{m['split']}/{key}"] == pytest.approx(value, rel=1e-12)
    for step in (2, 4):
        path = run_file.parent / "files" / rows[step]["images/heatmaps/path"]
        assert np.asarray(Image.open(path)).shape[:2] == (160 * SCALE, (3 * 160 + 2 * 4) * SCALE)


def test_missing_wandb_is_a_one_line_error(data_root, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "wandb", None)  # what `import wandb` sees when it is not installed
    code, _, err = run(capsys, "train", "gctn", *cli_flags(data_root, tmp_path / "run"), "--wandb")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "pip install 'tvf[wandb]'" in err
    assert not (tmp_path / "run").exists()  # refused before the run folder was made


def test_a_bad_init_is_refused_without_leaving_an_empty_run_folder(data_root, tmp_path, capsys):
    out = tmp_path / "new" / "run"
    code, _, err = run(capsys, "train", "gctn", *cli_flags(data_root, out), "--init", str(tmp_path / "no.pt"))
    assert code == 2 and len(err.strip().splitlines()) == 1 and "no.pt" in err
    assert not (tmp_path / "new").exists()  # both folders the command made are gone again


# --- relaunching from config.json -----------------------------------------------------------------------


def records(run_dir: Path) -> list[dict]:
    """metrics.jsonl without the timing (steps_per_s)."""
    lines = (run_dir / "metrics.jsonl").read_text().splitlines()
    return [{k: v for k, v in json.loads(x).items() if k != "steps_per_s"} for x in lines]


def test_a_run_relaunched_from_its_config_is_bit_identical(gctn_run, tmp_path, capsys):
    again = tmp_path / "again"
    code, _, err = run(capsys, "train", "--config", str(gctn_run / "config.json"), "--out", str(again))
    assert code == 0, err
    a = load_checkpoint(gctn_run / "checkpoints" / "last.pt", "gctn")
    b = load_checkpoint(again / "checkpoints" / "last.pt", "gctn")
    assert a.step == b.step == 4
    assert all(torch.equal(a.model[k], b.model[k]) for k in a.model)
    assert records(again) == records(gctn_run)
    first, second = (json.loads((r / "config.json").read_text()) for r in (gctn_run, again))
    assert second["train"]["config"] == str(gctn_run / "config.json")
    drop = lambda c: {**c, "train": {k: v for k, v in c["train"].items() if k not in ("out", "config")}}  # noqa: E731
    assert drop(first) == drop(second)  # the saved config is the resolved one: nothing else differs


def test_flags_beside_config_override_it_and_the_same_folder_needs_resume(gctn_run, tmp_path, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(gctn_run, copy)
    saved = json.loads((copy / "config.json").read_text())
    saved["train"]["out"] = str(copy)
    (copy / "config.json").write_text(json.dumps(saved))
    code, _, err = run(capsys, "train", "--config", str(copy / "config.json"))
    assert code == 2 and "--resume" in err  # the saved --out is the default and holds the run
    code, _, err = run(
        capsys, "train", "gctn", "--config", str(copy / "config.json"), "--resume", "--steps", "6"
    )
    assert code == 0, err
    assert load_checkpoint(copy / "checkpoints" / "last.pt", "gctn").step == 6
    assert json.loads((copy / "config.json").read_text())["train"]["steps"] == 6


def bad_config(tmp_path: Path, gctn_run: Path, edit) -> Path:
    saved = json.loads((gctn_run / "config.json").read_text())
    edit(saved)
    path = tmp_path / "config.json"
    path.write_text(json.dumps(saved))
    return path


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda c: c.pop("kind"), "not the config of a `tvf train` run"),
        (lambda c: c["train"].update(steps="four"), "train.steps is 'four', not a int"),
        (lambda c: c["train"].update(bogus=1), "unknown training flag(s) bogus"),
        (lambda c: c["train"].pop("data"), "lacks the training flag(s) data"),
    ],
    ids=["no-kind", "wrong-type", "unknown-flag", "missing-flag"],
)
def test_a_bad_config_is_a_one_line_error(gctn_run, tmp_path, capsys, edit, match):
    path = bad_config(tmp_path, gctn_run, edit)
    code, _, err = run(capsys, "train", "--config", str(path), "--out", str(tmp_path / "new"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert match in err


def test_another_kind_or_a_broken_file_is_a_one_line_error(gctn_run, tmp_path, capsys):
    code, _, err = run(capsys, "train", "vf", "--config", str(gctn_run / "config.json"))
    assert code == 2 and "is a gctn run, not a vf one" in err
    broken = tmp_path / "config.json"
    broken.write_text("{not json")
    for path, match in ((broken, "not valid JSON"), (tmp_path / "none.json", "is missing")):
        code, _, err = run(capsys, "train", "--config", str(path))
        assert code == 2 and match in err and len(err.strip().splitlines()) == 1
    code, _, err = run(capsys, "train", "--config")
    assert code == 2 and "needs a path" in err


def test_help_tells_how_to_relaunch(capsys):
    for argv in (["train", "--help"], ["train", "gctn", "--help"]):
        with pytest.raises(SystemExit):
            main(argv)
        out = " ".join(capsys.readouterr().out.split())
        assert "--config" in out and "override" in out


def test_the_experiment_passes_wandb_to_both_training_runs(tmp_path):
    from tvf.experiment.config import ExperimentConfig
    from tvf.experiment.pipeline import train_config

    on = ExperimentConfig(out=tmp_path, preset="smoke", wandb=True)
    assert all(train_config(on, kind).wandb for kind in ("gctn", "vf"))
    assert not train_config(replace(on, wandb=False), "gctn").wandb
