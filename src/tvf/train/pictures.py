"""Pictures of one fixed validation sample, logged to TensorBoard (and W&B) at validation time.

GCTN: the pick heat map and the place heat map (its best rotation, at the labelled pick) over the input
image, beside the goal; the heat is the logits scaled to 0..1 (their softmax is too peaked to see once
trained, and has the same order). VF: input | prediction | truth, colour above height. Every picture is
a uint8 (H, W, 3) array drawn with numpy and matplotlib's colour maps (no figure: it costs milliseconds).

Marks: a green square is the label (the demonstration's pick or place), a red cross the model's argmax;
on the VF input the action's pick is a green square and its place a cyan one.
"""

from __future__ import annotations

import numpy as np
import torch
from matplotlib import colormaps

from tvf.models.gctn import argmax_pixels, argmax_places
from tvf.models.images import from_rgbh, to_rgbh

HEIGHT_MAX = 0.14
"""Metres at the top of the height colour map (a 3-layer structure is 0.125 m)."""
SCALE = 2
"""Pictures are enlarged this many times (nearest), so marks stay visible at 160 x 160."""
LABEL_RGB = (0, 255, 0)
ARGMAX_RGB = (255, 0, 0)
PLACE_RGB = (0, 255, 255)


def height_rgb(height: np.ndarray) -> np.ndarray:
    """Height map (m) -> uint8 RGB (viridis, 0 .. HEIGHT_MAX)."""
    x = np.clip(np.asarray(height, np.float64) / HEIGHT_MAX, 0.0, 1.0)
    return (colormaps["viridis"](x)[..., :3] * 255).astype(np.uint8)


def heat_overlay(color: np.ndarray, weights: np.ndarray, alpha: float = 0.75) -> np.ndarray:
    """``weights`` (H, W, any scale) as an inferno heat map over the colour image: opaque (``alpha``) at
    the maximum, fading out towards the minimum so the scene stays visible."""
    w = np.asarray(weights, np.float64)
    w = (w - w.min()) / max(float(w.max() - w.min()), 1e-12)
    heat = colormaps["inferno"](w)[..., :3] * 255
    a = alpha * w[..., None]
    out = (1 - a) * np.asarray(color, np.float64) + a * heat
    return np.clip(out, 0, 255).astype(np.uint8)


def _set(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, rgb: tuple[int, int, int]) -> None:
    h, w = image.shape[:2]
    keep = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    image[rows[keep], cols[keep]] = rgb


def mark_square(image: np.ndarray, pixel, rgb=LABEL_RGB, half: int = 6) -> np.ndarray:
    """A copy of ``image`` with a hollow square of side 2*half+1 around ``pixel`` (row, col)."""
    out = image.copy()
    r, c = (int(v) for v in pixel)
    span = np.arange(-half, half + 1)
    for d in (-half, half):
        _set(out, np.full_like(span, r + d), c + span, rgb)
        _set(out, r + span, np.full_like(span, c + d), rgb)
    return out


def mark_cross(image: np.ndarray, pixel, rgb=ARGMAX_RGB, half: int = 4) -> np.ndarray:
    """A copy of ``image`` with a '+' of arm ``half`` at ``pixel`` (row, col)."""
    out = image.copy()
    r, c = (int(v) for v in pixel)
    span = np.arange(-half, half + 1)
    _set(out, np.full_like(span, r), c + span, rgb)
    _set(out, r + span, np.full_like(span, c), rgb)
    return out


def panel(rows: list[list[np.ndarray]], gap: int = 4) -> np.ndarray:
    """Equal-sized uint8 images in a grid with white gaps, enlarged :data:`SCALE` times."""
    h, w = rows[0][0].shape[:2]
    vgap = np.full((h, gap, 3), 255, np.uint8)
    lines = []
    for images in rows:
        parts = [p for i, img in enumerate(images) for p in ((vgap, img) if i else (img,))]
        lines.append(np.concatenate(parts, axis=1))
    hgap = np.full((gap, lines[0].shape[1], 3), 255, np.uint8)
    grid = np.concatenate([p for i, line in enumerate(lines) for p in ((hgap, line) if i else (line,))])
    return grid.repeat(SCALE, 0).repeat(SCALE, 1)


def _numpy_color(color: torch.Tensor) -> np.ndarray:
    return color[0].float().clamp(0, 255).cpu().numpy().astype(np.uint8)


@torch.no_grad()
def gctn_pictures(model, item: dict[str, torch.Tensor], device: torch.device) -> dict[str, np.ndarray]:
    """{"heatmaps": pick map | place map (best rotation at the labelled pick) | goal} of one sample."""
    b = {k: v.to(device) for k, v in item.items()}
    current = to_rgbh(b["current_color"], b["current_height"])
    goal = to_rgbh(b["goal_color"], b["goal_height"])
    pick_logits = model.pick_logits(current, goal).float()
    place_logits = model.place_map(current, goal, b["pick"]).float()  # (1, R, H, W) at the label
    place_best, channel = argmax_places(place_logits)
    color = _numpy_color(b["current_color"])
    pick_img = mark_square(heat_overlay(color, pick_logits[0].cpu().numpy()), b["pick"][0])
    pick_img = mark_cross(pick_img, argmax_pixels(pick_logits)[0])
    place_img = mark_square(
        heat_overlay(color, place_logits[0, int(channel[0])].cpu().numpy()), b["place"][0]
    )
    place_img = mark_cross(place_img, place_best[0])
    return {"heatmaps": panel([[pick_img, place_img, _numpy_color(b["goal_color"])]])}


@torch.no_grad()
def vf_pictures(model, item: dict[str, torch.Tensor], device: torch.device) -> dict[str, np.ndarray]:
    """{"foresight": input | prediction | truth, colour above height} of one sample."""
    b = {k: v.to(device) for k, v in item.items()}
    current = to_rgbh(b["current_color"], b["current_height"])
    color, height = from_rgbh(model.predict_rgbh(current, b["pick"], b["place"], b["yaw"]).float())
    colors = [_numpy_color(c) for c in (b["current_color"], color, b["next_color"])]
    heights = [
        height_rgb(h[0].float().cpu().numpy()) for h in (b["current_height"], height, b["next_height"])
    ]
    colors[0] = mark_square(mark_square(colors[0], b["pick"][0]), b["place"][0], PLACE_RGB)
    return {"foresight": panel([colors, heights])}
