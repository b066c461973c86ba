"""`tvf eval-vf --latent RUN`: the latent-dynamics baseline scored beside the VF and the two baselines."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_run import run
from data_factory import make_episode

from tvf.data import write_episode
from tvf.data.dataset import open_dataset
from tvf.data.format import episode_name
from tvf.data.samplers import VfSampler
from tvf.evaluate.foresight import evaluate_foresight, transition_metrics
from tvf.models.checkpoint import load_trained, save_checkpoint
from tvf.models.images import to_rgbh
from tvf.models.latent import LatentDynamics
from tvf.models.presets import get_preset
from tvf.models.vf import VisualForesight

EPISODES = (("stack-tower", "train", 3), ("stack-stair", "unseen", 2))


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A tiny test split (a 3-step training-task episode, a 2-step unseen one) and untrained smoke models."""
    root = tmp_path_factory.mktemp("latent-eval")
    for i, (task, _, steps) in enumerate(EPISODES):
        ep = make_episode(task, seed=1, steps=steps, split="test", rng_seed=i)
        write_episode(root / "data" / "test" / task / episode_name(ep.seed), ep)
    smoke = get_preset("smoke")
    vf = save_checkpoint(root / "vf.pt", VisualForesight(smoke, seed=0))
    latent = save_checkpoint(root / "latent.pt", LatentDynamics(smoke, seed=1))
    return root / "data", vf, latent


def test_latent_is_scored_like_the_vf_at_every_horizon(setup, tmp_path):
    data, vf, latent = setup
    alone = evaluate_foresight(vf, data, tmp_path / "vf", horizon=3)
    both = evaluate_foresight(vf, data, tmp_path / "both", horizon=3, latent_checkpoint=latent)
    for split in ("train", "unseen"):
        assert list(both[split]) == ["vf", "latent", "copy", "paste", "rigid", "rigid-falls"]
        assert {m: v for m, v in both[split].items() if m != "latent"} == alone[split]  # the rest unchanged
        assert list(both["horizons"][split]["latent"]) == ["1", "2", "3"][: 3 if split == "train" else 2]
        assert both["horizons"][split]["latent"]["1"] == both[split]["latent"]
    # one step: the latent model's own predictions of every transition, scored by the same metrics
    model = load_trained(latent, "latent")
    dataset = open_dataset(data, split="test")
    for task, split, steps in EPISODES:
        sampler = VfSampler(dataset.load_all(dataset.episodes[task]), augment=False, identity_fraction=0.0)
        b = sampler.batch(np.zeros(steps, np.int64), np.arange(steps))
        current = to_rgbh(b["current_color"], b["current_height"])
        target = to_rgbh(b["next_color"], b["next_height"])
        pred = model.predict_rgbh(current, b["pick"], b["place"], b["yaw"])
        expected = transition_metrics(pred, current, target)
        got = both[split]["latent"]
        assert got["transitions"] == steps
        for name, values in expected.items():
            assert got[name] == pytest.approx(float(np.mean(values)), rel=1e-5), (task, name)
        if steps >= 2:  # two steps: fed its own first prediction, scored against the real frame 2
            b1 = sampler.batch(np.zeros(1, np.int64), np.ones(1, np.int64))
            twice = model.predict_rgbh(pred[:1], b1["pick"], b1["place"], b1["yaw"])
            later = to_rgbh(b1["next_color"], b1["next_height"])
            two = transition_metrics(twice, current[:1], later)
            windows = both["horizons"][split]["latent"]["2"]
            assert windows["transitions"] == steps - 1
            if steps == 2:  # the only 2-step window
                assert windows["color_mae"] == pytest.approx(float(two["color_mae"][0]), rel=1e-5)
    text = (tmp_path / "both" / "metrics.md").read_text()
    assert "| latent | 1 |" in text and "| latent | 3 |" in text
    assert json.loads((tmp_path / "both" / "metrics.json").read_text()) == both


def test_cli_latent_flag_and_a_checkpoint_of_the_wrong_kind(setup, tmp_path, capsys):
    data, vf, latent = setup

    def eval_vf(vf_path, latent_path, out):
        return run(capsys, "eval-vf", "--vf", str(vf_path), "--latent", str(latent_path), "--data", str(data),
                   "--episodes", "1", "--out", str(tmp_path / out))  # fmt: skip

    code, stdout, err = eval_vf(vf, latent, "ok")
    assert code == 0, err
    assert "| latent | 2 |" in stdout  # the one-step table of the unseen task's 2 transitions
    for vf_path, latent_path, held, wanted in ((vf, vf, "vf", "latent"), (latent, latent, "latent", "vf")):
        code, _, err = eval_vf(vf_path, latent_path, f"bad-{wanted}")
        assert code == 2 and err.strip().count("\n") == 0
        assert f"holds a {held!r} model, expected {wanted!r}" in err
