"""Pictures of a TVF decision: the root's proposals on its place map, and the search tree drawn as a tree
(parent -> child edges, each node's imagined colour and height images, its score), the best path in blue."""

from __future__ import annotations

import io

import numpy as np
import torch

from tvf.geometry import bin_to_yaw
from tvf.models.images import from_rgbh
from tvf.viz.gctn import softmax_map
from tvf.viz.images import HEIGHT_DISPLAY_MAX

ROOT = -1
"""The parent index of depth-1 nodes: the real observation the search starts from."""
NODE_GAP = 0.08
"""Gap between a node's colour and height images, in image widths."""
COLUMN = 3.0
"""Horizontal distance between depth levels, in image widths (a node is 2 + NODE_GAP wide)."""
ROW = 1.5
"""Vertical distance between leaves, in image heights (room for the caption)."""
BEST = "royalblue"


def imagined_views(images: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Normalised RGB-H (N, 4, H, W) -> uint8 colour images (N, H, W, 3) and heights in metres (N, H, W)."""
    color, height = from_rgbh(images.detach().cpu().float())
    return color.clamp(0, 255).round().to(torch.uint8).numpy(), height.clamp(min=0).numpy()


def node_record(n) -> dict:
    """A JSON-able description of one node."""
    return {
        "index": n.index, "parent": n.parent, "depth": n.depth, "pick": n.pick.tolist(),
        "place": n.place.tolist(), "rotation": n.rotation, "distance": n.distance, "score": n.score,
    }  # fmt: skip


def plan_record(plan) -> dict:
    """A JSON-able description of a searched tree (with ``polished``: the executed first action, where
    the planner polishes it, ``--place-search``, ``--turn-search``)."""
    record = {
        "best": plan.best,
        "path": [n.index for n in plan.path],
        "counts": plan.counts,
        "nodes": [node_record(n) for n in plan.nodes],
    }
    if plan.polished is not None:
        record["polished"] = node_record(plan.polished)
    return record


def tree_edges(nodes) -> list[tuple[int, int]]:
    """One ``(parent, child)`` edge per node (``parent`` is :data:`ROOT` for the depth-1 nodes)."""
    return [(n.parent, n.index) for n in nodes]


def tree_layout(nodes) -> dict[int, tuple[float, float]]:
    """``(depth, row)`` of every node and of :data:`ROOT` (depth 0): leaves take consecutive rows in
    depth-first order, a parent sits at the mean row of its children."""
    children: dict[int, list[int]] = {ROOT: []}
    depth = {ROOT: 0}
    for n in nodes:
        children.setdefault(n.parent, []).append(n.index)
        children.setdefault(n.index, [])
        depth[n.index] = n.depth
    rows: dict[int, float] = {}
    next_row = 0

    def place(i: int) -> float:
        nonlocal next_row
        if children[i]:
            rows[i] = float(np.mean([place(c) for c in children[i]]))
        else:
            rows[i], next_row = float(next_row), next_row + 1
        return rows[i]

    place(ROOT)
    return {i: (float(depth[i]), rows[i]) for i in rows}


def _show(ax, image: np.ndarray, title: str, cmap: str | None = None) -> None:
    if cmap is None:
        ax.imshow(image, interpolation="nearest")
    else:
        ax.imshow(image, cmap=cmap, vmin=0, vmax=HEIGHT_DISPLAY_MAX, interpolation="nearest")
    ax.set_title(title, fontsize=9)
    ax.set_xticks([])
    ax.set_yticks([])


def _proposals_panel(ax, obs: dict, plan) -> None:
    """The current image under the root's place map, its picks (white) and proposed places (cyan)."""
    _show(ax, obs["color"], "root: place map, picks, proposals")
    ax.imshow(softmax_map(plan.place_logits).max(axis=0), cmap="inferno", alpha=0.6)
    proposals = plan.root_proposals
    picks = [plan.nodes[0].pick] if proposals.picks is None else np.unique(proposals.picks, axis=0)
    for pick in picks:  # the argmax pick, and the branched picks (the map is the argmax pick's)
        ax.plot(pick[1], pick[0], "o", ms=8, mfc="none", mec="white", mew=2)
    for i, (r, c) in enumerate(proposals.places):
        ax.plot(c, r, "s", ms=9, mfc="none", mec="cyan", mew=2)
        ax.annotate(str(i + 1), (c + 5, r - 5), color="cyan", fontsize=8)


def _node_images(ax, x: float, y: float, color: np.ndarray, height: np.ndarray, edge: str) -> None:
    """A node's colour and height images with their top-left corner at (x, y), framed in ``edge``."""
    import matplotlib.patches as patches

    ax.imshow(color, extent=(x, x + 1, y + 1, y), interpolation="nearest")
    hx = x + 1 + NODE_GAP
    ax.imshow(height, extent=(hx, hx + 1, y + 1, y), cmap="viridis", vmin=0, vmax=HEIGHT_DISPLAY_MAX,
              interpolation="nearest")  # fmt: skip
    for dx in (0.0, 1.0 + NODE_GAP):
        ax.add_patch(patches.Rectangle((x + dx, y), 1, 1, fill=False, ec=edge, lw=2 if edge == BEST else 0.8))


def node_caption(node, n_rotations: int, best: int) -> str:
    """``#4 d2 s=0.9615 *`` over ``D=0.0385, turn +90°`` (the star marks the best node)."""
    turn = np.degrees(float(bin_to_yaw(node.rotation, n_rotations)))
    star = " *" if node.index == best else ""
    return f"#{node.index} d{node.depth} s={node.score:.4f}{star}\nD={node.distance:.4f}, turn {turn:+.0f}°"


def draw_tree(ax, obs: dict, plan, n_rotations: int) -> list[tuple[int, int]]:
    """The search tree on ``ax``: the real state at the left, each level to its right, one line per
    parent -> child edge (the best path's in blue); returns the edges drawn."""
    layout = tree_layout(plan.nodes)
    on_path = {n.index for n in plan.path}
    colors, heights = imagined_views(plan.images)
    node_w = 2 + NODE_GAP

    def corner(i: int) -> tuple[float, float]:
        depth, row = layout[i]
        return depth * COLUMN, row * ROW

    edges = tree_edges(plan.nodes)
    for parent, child in edges:
        (px, py), (cx, cy) = corner(parent), corner(child)
        color, lw = (BEST, 2.2) if child in on_path else ("0.6", 0.8)
        ax.plot([px + node_w, cx], [py + 0.5, cy + 0.5], color=color, lw=lw, zorder=1)
    x, y = corner(ROOT)
    _node_images(ax, x, y, obs["color"], obs["height"], "forestgreen")
    ax.text(x, y + 1.05, "real (now)", fontsize=7, va="top")
    for n in plan.nodes:
        x, y = corner(n.index)
        _node_images(ax, x, y, colors[n.index], heights[n.index], BEST if n.index in on_path else "0.5")
        ax.text(x, y + 1.05, node_caption(n, n_rotations, plan.best), fontsize=7, va="top",
                color=BEST if n.index in on_path else "black")  # fmt: skip
    rows = max(r for _, r in layout.values()) + 1
    depth = max(d for d, _ in layout.values())
    ax.set_xlim(-0.1, depth * COLUMN + node_w + 0.1)
    ax.set_ylim((rows - 1) * ROW + 1.45, -0.1)
    ax.set_aspect("equal")
    ax.axis("off")
    return edges


def polished_caption(plan) -> str:
    """The title's note on the executed action where the planner polished it (empty otherwise)."""
    polished, first = plan.polished, plan.first
    if polished is None:
        return ""
    rows, cols = (int(v) for v in polished.place - first.place)
    turn = polished.rotation - first.rotation
    return f"\nexecuted: #{first.index} polished by ({rows:+d}, {cols:+d}) px and {turn:+d} turn bins"


def decision_figure(obs: dict, goal: dict, plan, n_rotations: int) -> bytes:
    """A PNG: current, goal and the root's place map with its proposals on top; below, the search tree
    (colour | height per node, the score s, the distance D to the goal and the turn; the best path and
    the best node's star in blue)."""
    import matplotlib  # pyplot is imported only after the headless backend is chosen

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    layout = tree_layout(plan.nodes)
    rows = max(r for _, r in layout.values()) + 1
    depth = max(d for d, _ in layout.values())
    tree_w = depth * COLUMN + 2 + NODE_GAP
    unit = 0.95  # inches per image width in the tree
    width = max(9.0, unit * tree_w)
    tree_h = unit * (rows * ROW)
    fig = plt.figure(figsize=(width, 3.4 + tree_h))
    grid = fig.add_gridspec(2, 4, height_ratios=[3.0, tree_h])
    _show(fig.add_subplot(grid[0, 0]), obs["color"], "current (real)")
    _show(fig.add_subplot(grid[0, 1]), obs["height"], "current height", "viridis")
    _show(fig.add_subplot(grid[0, 2]), goal["color"], "goal")
    _proposals_panel(fig.add_subplot(grid[0, 3]), obs, plan)
    tree = fig.add_subplot(grid[1, :])
    draw_tree(tree, obs, plan, n_rotations)
    tree.set_title(
        f"search tree: {len(plan.nodes)} imagined nodes, best #{plan.best} (blue path); each node: colour | "
        "height, score s, distance D to the goal, turn of its place" + polished_caption(plan),
        fontsize=9,
    )
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()
