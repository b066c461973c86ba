"""Multi-step foresight metrics (`tvf eval-vf --horizon H`): rollouts fed their own predictions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_run import run
from data_factory import make_episode

from tvf.data import write_episode
from tvf.data.dataset import open_dataset
from tvf.data.format import episode_name
from tvf.data.samplers import VfSampler
from tvf.errors import TvfError
from tvf.evaluate.foresight import (
    Snapped,
    evaluate_foresight,
    foresight_summary,
    paste_baseline,
    rollout_metrics,
    transition_metrics,
)
from tvf.models.checkpoint import load_trained, save_checkpoint
from tvf.models.images import HEIGHT_STD, heights_of, to_rgbh
from tvf.models.presets import get_preset
from tvf.models.vf import VisualForesight
from tvf.planning.levels import resting_levels

# (task, split, steps per episode): a 3- and a 2-step episode of a training task, one unseen task.
EPISODES = (("stack-tower", "train", (3, 2)), ("stack-stair", "unseen", (3,)))
H = 3


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A tiny test split on disk and an untrained smoke-preset VF checkpoint."""
    root = tmp_path_factory.mktemp("horizon")
    for i, (task, _, lengths) in enumerate(EPISODES):
        for j, steps in enumerate(lengths):
            ep = make_episode(task, seed=2 * j + 1, steps=steps, split="test", rng_seed=10 * i + j)
            write_episode(root / "data" / "test" / task / episode_name(ep.seed), ep)
    torch.manual_seed(0)
    ckpt = save_checkpoint(root / "vf.pt", VisualForesight(get_preset("smoke")).eval())
    return root / "data", ckpt


def _episodes(data: Path):
    dataset = open_dataset(data, split="test")
    return dataset, {task: dataset.load_all(dataset.episodes[task]) for task in dataset.tasks}


def _split_of(task: str) -> str:
    return next(split for t, split, _ in EPISODES if t == task)


def _pooled(per_task: dict[str, list[dict[str, np.ndarray]]]) -> dict[str, dict[str, float]]:
    """Per split: each metric's mean over all transitions of its tasks, and their number."""
    out = {}
    for split, parts in per_task.items():
        out[split] = {k: float(np.mean(np.concatenate([p[k] for p in parts]))) for k in parts[0]}
        out[split]["transitions"] = sum(len(p["color_mae"]) for p in parts)
    return out


def test_horizon_one_is_the_one_step_evaluation(setup, tmp_path):
    data, ckpt = setup
    one = evaluate_foresight(ckpt, data, tmp_path / "h1")
    assert "horizons" not in one and not (tmp_path / "h1" / "horizons.png").exists()
    assert "rollouts" not in (tmp_path / "h1" / "metrics.md").read_text()
    # The one-step evaluation as it was: every step's sample from the sampler, predicted in batches.
    model = load_trained(ckpt, "vf")
    _, episodes = _episodes(data)
    for method in ("vf", "copy", "paste"):
        parts: dict[str, list] = {}
        for task, eps in episodes.items():
            sampler = VfSampler(eps, augment=False, identity_fraction=0.0)
            items = [sampler.item(i) for i in range(len(sampler))]
            b = {k: torch.cat([it[k] for it in items]) for k in items[0]}
            current = to_rgbh(b["current_color"], b["current_height"])
            if method == "vf":
                pred = model.predict_rgbh(current, b["pick"], b["place"], b["yaw"])
            elif method == "paste":
                pred = paste_baseline(current, b["pick"], b["place"], b["yaw"], model.window)
            else:
                pred = current
            target = to_rgbh(b["next_color"], b["next_height"])
            parts.setdefault(_split_of(task), []).append(transition_metrics(pred, current, target))
        for split, expected in _pooled(parts).items():
            assert one[split][method] == pytest.approx(expected, rel=1e-6, abs=1e-9), (split, method)
    many = evaluate_foresight(ckpt, data, tmp_path / "h3", horizon=H)
    assert {k: v for k, v in many.items() if k != "horizons"} == one
    for split in ("train", "unseen"):
        for method in ("vf", "copy", "paste"):
            assert many["horizons"][split][method]["1"] == one[split][method]
    assert json.loads((tmp_path / "h3" / "metrics.json").read_text()) == many


def test_copy_baseline_compares_the_start_image_with_the_image_k_steps_later(setup, tmp_path):
    data, ckpt = setup
    horizons = evaluate_foresight(ckpt, data, tmp_path, horizon=H)["horizons"]
    _, episodes = _episodes(data)
    for k in range(1, H + 1):
        parts: dict[str, list] = {}
        for task, eps in episodes.items():
            for ep in eps:
                for t in range(ep.n_steps - k + 1):
                    start = to_rgbh(ep.color[t], ep.height[t])
                    later = to_rgbh(ep.color[t + k], ep.height[t + k])
                    parts.setdefault(_split_of(task), []).append(transition_metrics(start, start, later))
        for split, expected in _pooled(parts).items():
            assert horizons[split]["copy"][str(k)] == pytest.approx(expected, rel=1e-6, abs=1e-9), (split, k)
    # Windows of k steps: the training task has 3 + 2, 2 + 1, 1 + 0; the unseen one 3, 2, 1.
    assert [horizons["train"]["copy"][str(k)]["transitions"] for k in (1, 2, 3)] == [5, 3, 1]
    assert [horizons["unseen"]["vf"][str(k)]["transitions"] for k in (1, 2, 3)] == [3, 2, 1]


def test_paste_baseline_is_applied_to_its_own_output(setup):
    data, _ = setup
    _, episodes = _episodes(data)
    sampler = VfSampler(episodes["stack-stair"], augment=False, identity_fraction=0.0)
    per_window, _ = rollout_metrics(_ActionStub(sampler), sampler, H)
    b0, b1 = sampler.batch([0], [0]), sampler.batch([0], [1])
    start = to_rgbh(b0["current_color"], b0["current_height"])
    once = paste_baseline(start, b0["pick"], b0["place"], b0["yaw"], 44)
    twice = paste_baseline(once, b1["pick"], b1["place"], b1["yaw"], 44)
    expected = transition_metrics(twice, start, to_rgbh(b1["next_color"], b1["next_height"]))
    for name, value in expected.items():
        assert per_window["paste"][2][name][0] == pytest.approx(value[0], rel=1e-6)  # window from step 0


class _ActionStub:
    """A VF that knows each recorded action's real before and after images: it returns the real next
    image plus (input - real current image) plus ``drift_mm`` of height. Fed its own outputs along the
    recorded actions it is exact (drift 0), or off by k x drift after k steps."""

    window = 44

    def __init__(self, sampler: VfSampler, drift_mm: float = 0.0) -> None:
        ep = np.concatenate([np.full(e.n_steps, i) for i, e in enumerate(sampler.episodes)])
        step = np.concatenate([np.arange(e.n_steps) for e in sampler.episodes])
        b = sampler.batch(ep, step)
        self.cur = to_rgbh(b["current_color"], b["current_height"])
        self.nxt = to_rgbh(b["next_color"], b["next_height"])
        self.index = {self._key(b, i): i for i in range(len(ep))}
        assert len(self.index) == len(ep)
        self.drift = torch.tensor([0.0, 0.0, 0.0, drift_mm / 1000 / HEIGHT_STD]).view(1, 4, 1, 1)

    @staticmethod
    def _key(b: dict, i: int) -> tuple:
        return (*b["pick"][i].tolist(), *b["place"][i].tolist(), round(float(b["yaw"][i]), 5))

    def predict_rgbh(self, rgbh, pick, place, yaw) -> torch.Tensor:
        action = {"pick": pick, "place": place, "yaw": yaw}
        rows = [self.index[self._key(action, i)] for i in range(len(rgbh))]
        return self.nxt[rows] + (rgbh - self.cur[rows]) + self.drift


@pytest.mark.parametrize("drift_mm", [0.0, 2.0])
def test_a_perfect_model_fed_its_own_predictions_is_exact_at_every_horizon(setup, drift_mm):
    data, _ = setup
    dataset, episodes = _episodes(data)
    for task, eps in episodes.items():
        sampler = VfSampler(eps, augment=False, identity_fraction=0.0)
        per_window, _ = rollout_metrics(_ActionStub(sampler, drift_mm), sampler, H)
        assert sorted(per_window["vf"]) == [1, 2, 3]
        for k, metrics in per_window["vf"].items():
            assert metrics["color_mae"] == pytest.approx(0.0, abs=1e-6), (task, k)
            # Exact without drift; with drift the error grows by drift_mm per step fed back.
            assert metrics["height_mae_mm"] == pytest.approx(k * drift_mm, abs=1e-3), (task, k)
            assert metrics["changed_height_mae_mm"] == pytest.approx(k * drift_mm, abs=1e-3), (task, k)
            assert metrics["paper_height_l1"] == pytest.approx(
                k * drift_mm / 1000 / HEIGHT_STD * (160 / 204) ** 2, abs=1e-4
            )
    # The same through the per-split summary (a stub built for all episodes of every task).
    all_eps = [e for eps in episodes.values() for e in eps]
    stub = _ActionStub(VfSampler(all_eps, augment=False, identity_fraction=0.0), drift_mm)
    summary, figures = foresight_summary(stub, dataset, horizon=H)
    assert len(figures) == 2
    for split in ("train", "unseen"):
        for k in (1, 2, 3):
            assert summary[split]["vf"][k]["height_mae_mm"] == pytest.approx(k * drift_mm, abs=1e-3)
        assert summary[split]["copy"][3]["changed_height_mae_mm"] > 10


def test_cli_horizon_flag(setup, tmp_path, capsys):
    data, ckpt = setup
    out = tmp_path / "out"
    args = ("eval-vf", "--vf", str(ckpt), "--data", str(data), "--episodes", "1")
    code, stdout, _ = run(capsys, *args, "--out", str(out), "--horizon", "2")
    assert code == 0 and "| vf | 2 | 2 |" in stdout  # the first (3-step) episode of each task: 2 windows
    doc = json.loads((out / "metrics.json").read_text())
    assert set(doc) == {"train", "unseen", "horizons"}
    assert set(doc["horizons"]["train"]) == {"vf", "copy", "paste", "rigid", "rigid-falls"}
    assert set(doc["horizons"]["unseen"]["paste"]) == {"1", "2"}
    assert doc["horizons"]["unseen"]["paste"]["2"]["transitions"] == 2
    assert (out / "horizons.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "rollouts fed their own predictions" in (out / "metrics.md").read_text()
    for bad in ("0", "-1"):
        code, _, err = run(capsys, *args, "--out", str(tmp_path / "bad"), f"--horizon={bad}")
        assert code == 2 and err.strip().count("\n") == 0
        assert f"--horizon must be at least 1 (1 = one-step metrics only), got {bad}" in err
    assert not (tmp_path / "bad").exists()
    for wrong in (("--data", str(tmp_path / "no-data")), ("--vf", str(tmp_path / "no-vf.pt"))):
        code, _, err = run(capsys, *args, *wrong, "--out", str(tmp_path / "bad"))
        assert code == 2 and err.strip().count("\n") == 0 and wrong[1] in err
    assert not (tmp_path / "bad").exists()  # a bad input leaves no empty --out folder behind
    with pytest.raises(TvfError, match="--horizon must be at least 1"):
        evaluate_foresight(ckpt, data, tmp_path / "api", horizon=0)


def test_snapped_heights_change_the_vf_rows_only(setup, tmp_path, capsys):
    data, ckpt = setup
    args = ("eval-vf", "--vf", str(ckpt), "--data", str(data), "--episodes", "1", "--horizon", "2")
    docs = {}
    for flag in ("--no-snap-heights", "--snap-heights"):
        code, _, _ = run(capsys, *args, "--out", str(tmp_path / flag), flag)
        assert code == 0
        docs[flag] = json.loads((tmp_path / flag / "metrics.json").read_text())["horizons"]
    for split in ("train", "unseen"):
        plain, snapped = docs["--no-snap-heights"][split], docs["--snap-heights"][split]
        assert plain["copy"] == snapped["copy"] and plain["paste"] == snapped["paste"]
        assert plain["vf"]["1"]["height_mae_mm"] != snapped["vf"]["1"]["height_mae_mm"]
        assert plain["vf"]["1"]["color_mae"] == pytest.approx(snapped["vf"]["1"]["color_mae"], abs=1e-7)


def test_the_snapped_foresight_sets_moved_heights_to_resting_levels(setup):
    data, ckpt = setup
    _, episodes = _episodes(data)
    sampler = VfSampler(episodes["stack-stair"], augment=False, identity_fraction=0.0)
    b = sampler.batch(np.array([0]), np.array([0]))
    start = to_rgbh(b["current_color"], b["current_height"])
    vf = load_trained(ckpt, "vf")
    plain = vf.predict_rgbh(start, b["pick"], b["place"], b["yaw"])
    snapped = Snapped(vf).predict_rgbh(start, b["pick"], b["place"], b["yaw"])
    moved = (heights_of(plain) - heights_of(start)).abs() > 0.001
    assert moved.any() and (~moved).any()
    levels = resting_levels().to(torch.float32)
    gap = (heights_of(snapped)[moved][:, None] - levels).abs().min(dim=1).values
    assert gap.max() < 1e-6
    assert torch.equal(heights_of(snapped)[~moved], heights_of(plain)[~moved])
