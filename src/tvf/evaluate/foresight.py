"""How well the visual-foresight model predicts the next image, against two baselines.

Metrics per transition (current image, oracle action, next image), reported for the training tasks and
the unseen tasks separately:

* ``paper_color_l1`` / ``paper_height_l1``: the reference's metric — L1 of the *normalised* RGB-H over
  the image zero-padded by 22 px (204 x 204), i.e. Σ|ΔRGB_n| / (204²·3) and Σ|ΔH_n| / 204². The padded
  border adds zeros to the sum, so this equals the unpadded mean times (160/204)².
* ``color_mae``: colour mean absolute error in [0, 1]; ``height_mae_mm``: height MAE in millimetres;
  ``changed_height_mae_mm``: height MAE on the pixels whose true height changed by more than 5 mm.

Baselines: ``copy`` predicts the input unchanged; ``paste`` pastes the place mask (the rotated window
around the pick, no network) onto the input at the place pixel; ``rigid`` moves the picked block as a
rigid body (:class:`tvf.planning.rigid.RigidForesight`, the search's ``--foresight rigid``), and
``rigid-falls`` also tips it off where it would not rest (``--foresight rigid-falls``); ``latent``,
when a latent-dynamics run is given (:class:`tvf.models.latent.LatentDynamics`), is a learned model
scored like the VF.

Multi-step (``horizon`` > 1, :func:`rollout_metrics`): from the real image of every step t, each method
is fed its own output along the recorded actions of steps t, t+1, ... and scored against the real image
k steps later, for k = 1..horizon; changed pixels are then counted against the rollout's start image
(what matters for planning). Horizon 1 is the one-step evaluation above, number for number.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from tvf.data.dataset import open_dataset
from tvf.data.samplers import VfSampler
from tvf.errors import TvfError
from tvf.io import atomic_write_bytes, check_output_dir
from tvf.models.checkpoint import load_trained
from tvf.models.images import from_rgbh, to_rgbh
from tvf.models.vf import encode_action, height_changed, paste_place_window
from tvf.planning.levels import snap_heights
from tvf.planning.rigid import RIGID_FORESIGHTS, rigid_foresight
from tvf.tasks import BUILTIN, TaskTable

PAPER_PAD = 22
METHODS = ("vf", "copy", "paste", "rigid", "rigid-falls")
"""The methods of every evaluation; learned models passed as ``others`` (``latent``) come after the VF."""
RIGID = {name: rigid_foresight(name) for name in RIGID_FORESIGHTS}


def paste_baseline(rgbh: torch.Tensor, pick, place, yaw, window: int) -> torch.Tensor:
    """The input with the rotated pick window pasted at the place pixel (no learning)."""
    return paste_place_window(rgbh, encode_action(rgbh, pick, place, yaw, window), place, window)


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
    changed = height_changed(ch, th)
    herr = (ph - th).abs() * 1000
    changed_err = (herr * changed).flatten(1).sum(1) / changed.flatten(1).sum(1).clamp(min=1)
    return {
        "paper_color_l1": (diff[:, :3].flatten(1).mean(1) * scale).numpy(),
        "paper_height_l1": (diff[:, 3].flatten(1).mean(1) * scale).numpy(),
        "color_mae": ((pc - tc).abs().flatten(1).mean(1) / 255.0).numpy(),
        "height_mae_mm": herr.flatten(1).mean(1).numpy(),
        "changed_height_mae_mm": changed_err.numpy(),
    }


class Foresight(Protocol):
    """What the evaluation needs of a VF model (:class:`tvf.models.vf.VisualForesight` or a test stub)."""

    window: int

    def predict_rgbh(self, rgbh: torch.Tensor, pick, place, yaw) -> torch.Tensor: ...


class OnDevice:
    """A VF on ``device`` behind the CPU interface the metrics use (inputs moved there, outputs back)."""

    def __init__(self, model, device: torch.device) -> None:
        self.model, self.device, self.window = model, device, model.window

    def predict_rgbh(self, rgbh: torch.Tensor, pick, place, yaw) -> torch.Tensor:
        moved = [torch.as_tensor(x).to(self.device) for x in (rgbh, pick, place, yaw)]
        return self.model.predict_rgbh(*moved).cpu()


class Snapped:
    """A foresight whose every moved height is set to the nearest resting level, as the search snaps it
    with ``snap_heights`` (:func:`tvf.planning.levels.snap_heights`)."""

    def __init__(self, model: Foresight) -> None:
        self.model, self.window = model, model.window

    def predict_rgbh(self, rgbh: torch.Tensor, pick, place, yaw) -> torch.Tensor:
        return snap_heights(self.model.predict_rgbh(rgbh, pick, place, yaw), rgbh)


PerWindow = dict[str, dict[int, dict[str, np.ndarray]]]
"""{method: {horizon k: {metric: one value per rollout window}}}."""


@torch.no_grad()
def rollout_metrics(
    model: Foresight, sampler: VfSampler, horizon: int, others: dict[str, Foresight] | None = None
) -> tuple[PerWindow, dict]:
    """Open-loop rollouts of every method along the episodes' recorded actions, 1..``horizon`` steps.

    A rollout starts from the real image of every step t of every episode; step k (1-based) feeds the
    method its own step k-1 output with the action of step t+k-1 (as :meth:`VfSampler.batch` turns it
    into model inputs) and compares with the real frame t+k. Horizon k thus covers every window of k
    steps inside an episode. "Changed" pixels (``changed_height_mae_mm``) are those whose true height
    differs from the rollout's start image by more than 5 mm. ``copy`` keeps the start image; ``paste``
    pastes onto its own previous output, and ``rigid`` / ``rigid-falls`` move the block on their own.
    ``others`` ({name: model}) are rolled out as the VF is. One batched model call per horizon step and
    model covers all rollouts. Returns the per-window metrics and the first step's batch with the VF's
    prediction (``pred``).
    """
    n_steps = np.array([e.n_steps for e in sampler.episodes], np.int64)
    ep = np.repeat(np.arange(len(n_steps)), n_steps)
    start = np.concatenate([np.arange(n) for n in n_steps])
    left = n_steps[ep] - start  # steps from each window's start to the episode's end
    others = others or {}
    methods = ("vf", *others, "copy", "paste", *RIGID)
    out: PerWindow = {m: {} for m in methods}
    active = np.arange(len(ep))
    state: dict[str, torch.Tensor] = {}
    origin = torch.empty(0)
    first: dict = {}
    for k in range(1, horizon + 1):
        keep = left[active] >= k
        if not keep.any():
            break
        active = active[keep]
        b = sampler.batch(ep[active], start[active] + k - 1)
        target = to_rgbh(b["next_color"], b["next_height"])
        if k == 1:
            origin = to_rgbh(b["current_color"], b["current_height"])
            state = dict.fromkeys(methods, origin)
        else:
            sel = torch.from_numpy(keep)
            origin = origin[sel]
            state = {m: v[sel] for m, v in state.items()}
        state = {
            "vf": model.predict_rgbh(state["vf"], b["pick"], b["place"], b["yaw"]),
            **{n: m.predict_rgbh(state[n], b["pick"], b["place"], b["yaw"]) for n, m in others.items()},
            "copy": origin,
            "paste": paste_baseline(state["paste"], b["pick"], b["place"], b["yaw"], model.window),
            **{n: f.predict_rgbh(state[n], b["pick"], b["place"], b["yaw"]) for n, f in RIGID.items()},
        }
        for method, pred in state.items():
            out[method][k] = transition_metrics(pred, origin, target)
        if k == 1:
            first = {**b, "pred": state["vf"]}
    return out, first


def foresight_summary(
    model: Foresight, dataset, max_episodes: int = 20, horizon: int = 1, figure_per_task: int = 1,
    tasks: TaskTable | None = None, others: dict[str, Foresight] | None = None,
) -> tuple[dict, list[tuple[str, dict]]]:  # fmt: skip
    """Metrics averaged per split, method and horizon: ({split: {method: {k: {metric, "transitions"}}}},
    figure samples of the VF). ``dataset`` is a :class:`tvf.data.dataset.DemoDataset`; ``tasks`` tells
    each task's split (training or unseen; pass the table of a --task-file); ``others`` are more learned
    models scored beside the VF (:func:`rollout_metrics`)."""
    table = tasks or BUILTIN
    results: dict[str, dict[str, dict[int, dict[str, list[float]]]]] = {}
    figures: list[tuple[str, dict]] = []
    for task in dataset.tasks:
        split = table.get(task).split
        episodes = dataset.load_all(dataset.episodes[task][:max_episodes])
        sampler = VfSampler(episodes, augment=False, identity_fraction=0.0)
        per_window, first = rollout_metrics(model, sampler, horizon, others)
        for method, by_k in per_window.items():
            for k, metrics in by_k.items():
                per = results.setdefault(split, {}).setdefault(method, {}).setdefault(k, {})
                for name, v in metrics.items():
                    per.setdefault(name, []).extend(v.tolist())
        for i in range(min(figure_per_task, len(first["pred"]))):
            figures.append((task, {name: v[i] for name, v in first.items()}))
    summary = {
        split: {m: {k: _mean(per) for k, per in by_k.items()} for m, by_k in methods.items()}
        for split, methods in results.items()
    }
    return summary, figures


def _mean(per: dict[str, list[float]]) -> dict:
    """Each metric's mean over the transitions, and their number."""
    return {name: float(np.mean(v)) for name, v in per.items()} | {"transitions": len(per["color_mae"])}


def check_horizon(horizon: int) -> None:
    """Raise a one-line TvfError unless ``horizon`` is at least 1."""
    if horizon < 1:
        raise TvfError(f"--horizon must be at least 1 (1 = one-step metrics only), got {horizon}")


def evaluate_foresight(vf_checkpoint: str | Path | None, data: str | Path, out: Path, max_episodes: int = 20,
                       figure_per_task: int = 1, horizon: int = 1, tasks: TaskTable | None = None,
                       device: str = "cpu", latent_checkpoint: str | Path | None = None,
                       snap_heights: bool = False) -> dict:  # fmt: skip
    """Evaluate on the test split's transitions; writes metrics.json, metrics.md and figures.

    ``latent_checkpoint`` (a latent-dynamics run, .pt or .safetensors) adds the method ``latent``. The
    one-step metrics are at the top level ({split: {method: metrics}}). With ``horizon`` > 1 a
    ``horizons`` section {split: {method: {"k": metrics}}} for k = 1..horizon (see
    :func:`rollout_metrics`) is added, with tables in metrics.md and the plot horizons.png.
    ``snap_heights`` scores the VF through :class:`Snapped`.
    """
    check_horizon(horizon)
    model: Foresight = OnDevice(load_trained(vf_checkpoint, "vf", device), torch.device(device))
    if snap_heights:
        model = Snapped(model)
    others = {}
    if latent_checkpoint is not None:
        others["latent"] = OnDevice(load_trained(latent_checkpoint, "latent", device), torch.device(device))
    dataset = open_dataset(data, split="test" if (Path(data) / "test").is_dir() else None)
    out = check_output_dir(out)  # after the inputs, so a bad one leaves no empty folder behind
    by_k, figures = foresight_summary(model, dataset, max_episodes, horizon, figure_per_task, tasks, others)
    summary: dict = {split: {m: per[1] for m, per in methods.items()} for split, methods in by_k.items()}
    if horizon > 1:
        summary["horizons"] = {
            split: {m: {str(k): v for k, v in per.items()} for m, per in methods.items()}
            for split, methods in by_k.items()
        }
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out / "metrics.json", json.dumps(summary, indent=1).encode())
    atomic_write_bytes(out / "metrics.md", metrics_markdown(summary).encode())
    atomic_write_bytes(out / "predictions.png", figure_grid(figures))
    if horizon > 1:
        atomic_write_bytes(out / "horizons.png", horizon_plot(summary["horizons"]))
    return summary


KEYS = ("paper_color_l1", "paper_height_l1", "color_mae", "height_mae_mm", "changed_height_mae_mm")


def metrics_markdown(summary: dict) -> str:
    """One table per split (one-step metrics), then, with a ``horizons`` section, a table per split with
    a row per method and horizon."""
    keys = list(KEYS)
    lines = ["# Visual foresight: prediction quality", ""]
    for split, methods in summary.items():
        if split == "horizons":
            continue
        lines += [f"## {split} tasks", "", "| method | transitions | " + " | ".join(keys) + " |",
                  "|---" * (len(keys) + 2) + "|"]  # fmt: skip
        for m, v in methods.items():
            lines.append(f"| {m} | {v['transitions']} | " + " | ".join(f"{v[k]:.4f}" for k in keys) + " |")
        lines.append("")
    for split, methods in summary.get("horizons", {}).items():
        header = "| method | horizon | transitions | " + " | ".join(keys) + " |"
        lines += [f"## {split} tasks: rollouts fed their own predictions", "", header]
        lines.append("|---" * (len(keys) + 3) + "|")
        for m, per in methods.items():
            for h, v in per.items():
                values = " | ".join(f"{v[k]:.4f}" for k in keys)
                lines.append(f"| {m} | {h} | {v['transitions']} | {values} |")
        lines.append("")
    return "\n".join(lines)


def horizon_plot(horizons: dict) -> bytes:
    """Changed-pixel height error (mm) against the horizon, a line per method, a panel per split (PNG)."""
    import matplotlib  # pyplot is imported only after the headless backend is chosen

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = max(len(horizons), 1)
    fig, axes = plt.subplots(1, n, figsize=(4.5 * n, 3.5), squeeze=False)
    for ax, (split, methods) in zip(axes[0], horizons.items(), strict=False):
        for m, per in methods.items():
            ks = [int(k) for k in per]
            ax.plot(ks, [per[k]["changed_height_mae_mm"] for k in per], "o-", label=m)
            ax.set_xticks(ks)
        ax.set_title(f"{split} tasks", fontsize=10)
        ax.set_xlabel("horizon (steps fed back)")
        ax.set_ylabel("height MAE on changed pixels (mm)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    plt.close(fig)
    return buf.getvalue()


def figure_grid(samples: list[tuple[str, dict]]) -> bytes:
    """Rows of: input, action (place mask), prediction, truth, height error; as PNG bytes."""
    import matplotlib  # pyplot is imported only after the headless backend is chosen

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
