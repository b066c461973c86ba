"""How well the visual-foresight model predicts the next image, against two baselines.

Metrics per transition (current image, oracle action, next image), reported for the training tasks and
the unseen tasks separately:

* ``paper_color_l1`` / ``paper_height_l1``: the reference's metric — L1 of the *normalised* RGB-H over
  the image zero-padded by 22 px (204 x 204), i.e. Σ|ΔRGB_n| / (204²·3) and Σ|ΔH_n| / 204². The padded
  border adds zeros to the sum, so this equals the unpadded mean times (160/204)².
* ``color_mae``: colour mean absolute error in [0, 1]; ``height_mae_mm``: height MAE in millimetres;
  ``changed_height_mae_mm``: height MAE on the pixels whose true height changed by more than 5 mm.

Baselines: ``copy`` predicts the input unchanged; ``paste`` pastes the place mask (the rotated window
around the pick, no network) onto the input at the place pixel.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import torch

from tvf.data.dataset import open_dataset
from tvf.data.samplers import VfSampler
from tvf.io import atomic_write_bytes
from tvf.models.checkpoint import load_trained
from tvf.models.images import from_rgbh, to_rgbh
from tvf.models.vf import encode_action, square_masks
from tvf.tasks import BUILTIN, TaskTable

PAPER_PAD = 22
CHANGED_MM = 5.0
METHODS = ("vf", "copy", "paste")


def paste_baseline(rgbh: torch.Tensor, pick, place, yaw, window: int) -> torch.Tensor:
    """The input with the rotated pick window pasted at the place pixel (no learning)."""
    enc = encode_action(rgbh, pick, place, yaw, window)
    mask = square_masks(place, window, rgbh.shape[-2], rgbh.shape[-1])
    return rgbh * (1 - mask) + enc[:, 5:9] * mask


def transition_metrics(
    pred: torch.Tensor, current: torch.Tensor, target: torch.Tensor
) -> dict[str, np.ndarray]:
    """Per-sample metrics of normalised RGB-H predictions (B, 4, H, W)."""
    h, w = target.shape[-2:]
    scale = (h * w) / ((h + 2 * PAPER_PAD) * (w + 2 * PAPER_PAD))
    diff = (pred - target).abs()
    pc, ph = from_rgbh(pred)
    tc, th = from_rgbh(target)
    _, ch = from_rgbh(current)
    changed = (th - ch).abs() * 1000 > CHANGED_MM
    herr = (ph - th).abs() * 1000
    changed_err = (herr * changed).flatten(1).sum(1) / changed.flatten(1).sum(1).clamp(min=1)
    return {
        "paper_color_l1": (diff[:, :3].flatten(1).mean(1) * scale).numpy(),
        "paper_height_l1": (diff[:, 3].flatten(1).mean(1) * scale).numpy(),
        "color_mae": ((pc - tc).abs().flatten(1).mean(1) / 255.0).numpy(),
        "height_mae_mm": herr.flatten(1).mean(1).numpy(),
        "changed_height_mae_mm": changed_err.numpy(),
    }


@torch.no_grad()
def evaluate_foresight(vf_checkpoint: str | Path | None, data: str | Path, out: Path, max_episodes: int = 20,
                       figure_per_task: int = 1, tasks: TaskTable | None = None) -> dict:  # fmt: skip
    """Evaluate on the test split's oracle transitions; writes metrics.json, metrics.md and figures.

    ``tasks`` tells each episode's split (training or unseen task); pass the table of a --task-file.
    """
    table = tasks or BUILTIN
    model = load_trained(vf_checkpoint, "vf")
    dataset = open_dataset(data, split="test" if (Path(data) / "test").is_dir() else None)
    results: dict[str, dict[str, dict[str, list[float]]]] = {}
    figures: list[tuple[str, dict]] = []
    for task in dataset.tasks:
        split = table.get(task).split
        episodes = dataset.load_all(dataset.episodes[task][:max_episodes])
        sampler = VfSampler(episodes, augment=False, identity_fraction=0.0)
        items = [sampler.item(i) for i in range(len(sampler))]
        for start in range(0, len(items), 16):
            b = {k: torch.cat([it[k] for it in items[start : start + 16]]) for k in items[0]}
            current = to_rgbh(b["current_color"], b["current_height"])
            target = to_rgbh(b["next_color"], b["next_height"])
            preds = {
                "vf": model.predict_rgbh(current, b["pick"], b["place"], b["yaw"]),
                "copy": current,
                "paste": paste_baseline(current, b["pick"], b["place"], b["yaw"], model.window),
            }
            for method, pred in preds.items():
                per = results.setdefault(split, {}).setdefault(method, {})
                for k, v in transition_metrics(pred, current, target).items():
                    per.setdefault(k, []).extend(v.tolist())
            if start == 0:
                for i in range(min(figure_per_task, len(items))):
                    figures.append((task, {k: v[i] for k, v in {**b, "pred": preds["vf"]}.items()}))
    summary = {
        split: {m: {k: float(np.mean(v)) for k, v in per.items()} | {"transitions": len(per["color_mae"])}
                for m, per in methods.items()}
        for split, methods in results.items()
    }  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out / "metrics.json", json.dumps(summary, indent=1).encode())
    atomic_write_bytes(out / "metrics.md", metrics_markdown(summary).encode())
    atomic_write_bytes(out / "predictions.png", figure_grid(figures))
    return summary


def metrics_markdown(summary: dict) -> str:
    keys = ["paper_color_l1", "paper_height_l1", "color_mae", "height_mae_mm", "changed_height_mae_mm"]
    lines = ["# Visual foresight: prediction quality", ""]
    for split, methods in summary.items():
        lines += [f"## {split} tasks", "", "| method | transitions | " + " | ".join(keys) + " |",
                  "|---" * (len(keys) + 2) + "|"]  # fmt: skip
        for m, v in methods.items():
            lines.append(f"| {m} | {v['transitions']} | " + " | ".join(f"{v[k]:.4f}" for k in keys) + " |")
        lines.append("")
    return "\n".join(lines)


def figure_grid(samples: list[tuple[str, dict]]) -> bytes:
    """Rows of: input, action (place mask), prediction, truth, height error; as PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = max(len(samples), 1)
    fig, axes = plt.subplots(n, 5, figsize=(12, 2.5 * n), squeeze=False)
    titles = ["input", "action", "prediction", "truth", "height error (mm)"]
    for row, (task, s) in enumerate(samples):
        current = to_rgbh(s["current_color"][None], s["current_height"][None])
        enc = encode_action(current, s["pick"][None], s["place"][None], s["yaw"][None], 44)
        action_color, _ = from_rgbh(enc[:, 5:9] + (enc[:, 5:9] == 0) * current)
        pc, ph = from_rgbh(s["pred"][None])
        err = (ph[0] - s["next_height"]).abs() * 1000
        panels = [s["current_color"], action_color[0], pc[0], s["next_color"]]
        for col, img in enumerate(panels):
            axes[row, col].imshow(np.clip(img.numpy() / 255.0, 0, 1))
        axes[row, 1].plot(s["pick"][1], s["pick"][0], "wo", mfc="none")
        axes[row, 1].plot(s["place"][1], s["place"][0], "cs", mfc="none")
        im = axes[row, 4].imshow(err.numpy(), cmap="magma", vmin=0, vmax=40)
        fig.colorbar(im, ax=axes[row, 4], fraction=0.046)
        axes[row, 0].set_ylabel(task, fontsize=8)
        for col in range(5):
            axes[row, col].set_xticks([])
            axes[row, col].set_yticks([])
            if row == 0:
                axes[row, col].set_title(titles[col], fontsize=9)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    plt.close(fig)
    return buf.getvalue()
