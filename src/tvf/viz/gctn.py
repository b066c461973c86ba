"""Pictures of a GCTN decision: pick and place heat maps over the image, with the chosen action."""

from __future__ import annotations

import io

import numpy as np
import torch

from tvf.geometry import bin_to_yaw
from tvf.models.images import to_rgbh


def softmax_map(logits: torch.Tensor) -> np.ndarray:
    """Logits of any shape -> probabilities of the same shape (softmax over all entries)."""
    flat = torch.softmax(logits.flatten().float(), 0)
    return flat.reshape(logits.shape).cpu().numpy()


def decision_maps(model, obs: dict, goal: dict) -> dict[str, np.ndarray]:
    """The greedy decision and its maps: pick probabilities (H, W), place probabilities (R, H, W)."""
    current = to_rgbh(obs["color"], obs["height"])
    target = to_rgbh(goal["color"], goal["height"])
    pick, place, rot, maps = model.act(current, target)
    return {
        "pick": pick[0].numpy(),
        "place": place[0].numpy(),
        "rot_bin": int(rot[0]),
        "pick_prob": softmax_map(maps["pick"][0]),
        "place_prob": softmax_map(maps["place"][0]),
    }


def _draw_action(ax, pick: np.ndarray, place: np.ndarray | None, yaw: float | None) -> None:
    ax.plot(pick[1], pick[0], "o", ms=9, mfc="none", mec="white", mew=2)
    if place is not None:
        ax.plot(place[1], place[0], "s", ms=10, mfc="none", mec="cyan", mew=2)
        if yaw is not None:
            # an arrow showing the block's turn: x (cols) and y (rows) follow the world frame
            dx, dy = 10 * np.cos(yaw), 10 * np.sin(yaw)
            ax.arrow(place[1], place[0], dx, dy, color="cyan", width=0.8, head_width=3)


def gctn_figure(obs: dict, goal: dict, d: dict, n_rotations: int) -> bytes:
    """A PNG: current image with the pick map, the place map (max over rotations), the goal."""
    import matplotlib  # pyplot is imported only after the headless backend is chosen

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    yaw = float(bin_to_yaw(d["rot_bin"], n_rotations))
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.3))
    axes[0].imshow(obs["color"])
    axes[0].imshow(d["pick_prob"], cmap="inferno", alpha=0.6)
    axes[0].set_title("pick probability")
    _draw_action(axes[0], d["pick"], None, None)
    axes[1].imshow(obs["color"])
    axes[1].imshow(d["place_prob"].max(0), cmap="inferno", alpha=0.6)
    rotations = len(d["place_prob"])
    axes[1].set_title(f"place probability (max over {rotations} rotations), turn {np.degrees(yaw):.0f}°")
    _draw_action(axes[1], d["pick"], d["place"], yaw)
    axes[2].imshow(goal["color"])
    axes[2].set_title("goal")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()
