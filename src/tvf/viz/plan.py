"""Pictures of TVF decisions: a decision's search tree, and an episode GIF beside its imagined best paths."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import torch

from tvf.models.images import from_rgbh
from tvf.viz.gctn import softmax_map
from tvf.viz.images import save_gif, side_by_side

SCALE = 2


def imagined_colors(images: torch.Tensor) -> np.ndarray:
    """Normalised RGB-H (N, 4, H, W) -> uint8 colour images (N, H, W, 3)."""
    color, _ = from_rgbh(images.detach().cpu())
    return color.clamp(0, 255).round().to(torch.uint8).numpy()


def _enlarge(image: np.ndarray) -> np.ndarray:
    return image.repeat(SCALE, 0).repeat(SCALE, 1)


def _framed(image: np.ndarray, color: tuple[int, int, int], width: int = 3) -> np.ndarray:
    out = image.copy()
    out[:width], out[-width:], out[:, :width], out[:, -width:] = color, color, color, color
    return out


def episode_frame(real: np.ndarray, plan, goal: np.ndarray) -> np.ndarray:
    """One GIF frame: the real image (green frame), the imagined best path (blue frames), the goal (grey)."""
    panels = [_framed(_enlarge(real), (40, 170, 40))]
    if plan is not None and plan.images is not None:
        path = imagined_colors(plan.images[[n.index for n in plan.path]])
        panels += [_framed(_enlarge(img), (40, 90, 220)) for img in path]
    panels.append(_framed(_enlarge(goal), (150, 150, 150)))
    return side_by_side(*panels)


def _pad_width(frames: list[np.ndarray]) -> list[np.ndarray]:
    width = max(f.shape[1] for f in frames)
    return [np.pad(f, ((0, 0), (0, width - f.shape[1]), (0, 0)), constant_values=255) for f in frames]


def episode_gif(path: Path, steps: list, fps: float = 1.0) -> None:
    """A GIF of a recorded episode (:func:`tvf.evaluate.recording.record_episode`): per step the real
    image, the imagined best path, the goal; the last frame is the final state."""
    frames = [episode_frame(s.obs["color"], s.plan, s.goal["color"]) for s in steps]
    save_gif(path, _pad_width(frames), fps)


def plan_record(plan) -> dict:
    """A JSON-able description of a searched tree."""
    return {
        "best": plan.best,
        "path": [n.index for n in plan.path],
        "counts": plan.counts,
        "nodes": [
            {"index": n.index, "parent": n.parent, "depth": n.depth, "pick": n.pick.tolist(),
             "place": n.place.tolist(), "rotation": n.rotation, "distance": n.distance, "score": n.score}
            for n in plan.nodes
        ],
    }  # fmt: skip


def _show(ax, image: np.ndarray, title: str, edge: str | None = None) -> None:
    ax.imshow(image)
    ax.set_title(title, fontsize=8)
    ax.set_xticks([])
    ax.set_yticks([])
    if edge:
        for spine in ax.spines.values():
            spine.set_edgecolor(edge)
            spine.set_linewidth(3)


def decision_figure(obs: dict, goal: dict, plan, n_rotations: int) -> bytes:
    """A PNG: current, goal and place map with the proposals; then every level's imagined nodes with scores.

    The best path's nodes are framed in blue; the best node's title is marked with a star.
    """
    import matplotlib  # pyplot is imported only after the headless backend is chosen

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    levels = sorted({n.depth for n in plan.nodes})
    per_level = [[n for n in plan.nodes if n.depth == d] for d in levels]
    cols = max(3, min(9, max(len(p) for p in per_level)))
    rows = 1 + sum(-(-len(p) // cols) for p in per_level)
    fig, axes = plt.subplots(rows, cols, figsize=(1.9 * cols, 2.1 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    place = softmax_map(plan.place_logits).max(axis=0)
    _show(axes[0, 0], obs["color"], "current (real)")
    _show(axes[0, 1], goal["color"], "goal")
    _show(axes[0, 2], obs["color"], "place map (max over rotations)")
    axes[0, 2].imshow(place, cmap="inferno", alpha=0.6)
    proposals = plan.root_proposals
    picks = [plan.nodes[0].pick] if proposals.picks is None else np.unique(proposals.picks, axis=0)
    for pick in picks:  # the argmax pick, and the branched picks (the map is the argmax pick's)
        axes[0, 2].plot(pick[1], pick[0], "o", ms=8, mfc="none", mec="white", mew=2)
    for i, (r, c) in enumerate(proposals.places):
        axes[0, 2].plot(c, r, "s", ms=9, mfc="none", mec="cyan", mew=2)
        axes[0, 2].annotate(str(i + 1), (c + 5, r - 5), color="cyan", fontsize=8)
    on_path = {n.index for n in plan.path}
    colors = imagined_colors(plan.images)
    row = 1
    for nodes in per_level:
        for j, n in enumerate(nodes):
            ax = axes[row + j // cols, j % cols]
            ax.axis("on")
            star = " *" if n.index == plan.best else ""
            title = f"d{n.depth} #{n.index} s={n.score:.4f}{star}"
            _show(ax, colors[n.index], title, "royalblue" if n.index in on_path else None)
        row += -(-len(nodes) // cols)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()
