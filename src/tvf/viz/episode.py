"""Pictures of an episode: colour and height side by side, each step's pick and place drawn on top."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from tvf.data.format import DataError, Episode
from tvf.geometry import world_to_pixel
from tvf.viz.images import height_to_rgb, save_gif, save_png, side_by_side

SCALE = 2
ORACLE_COLOURS = ((40, 220, 60), (40, 120, 255))
"""Pick and place marks of oracle steps (green, blue)."""
RANDOM_COLOURS = ((255, 170, 0), (255, 60, 200))
"""Pick and place marks of random steps (orange, magenta)."""


def _panel(color: np.ndarray, height: np.ndarray) -> np.ndarray:
    panel = side_by_side(color, height_to_rgb(height), gap=4)
    return panel.repeat(SCALE, 0).repeat(SCALE, 1)


def _draw_action(
    image: np.ndarray, pick: np.ndarray, place: np.ndarray, is_random: bool, offsets
) -> np.ndarray:
    """Mark pick (cross) and place (circle with a tick showing the block's turn), joined by a line."""

    img = Image.fromarray(image)
    draw = ImageDraw.Draw(img)
    pick_c, place_c = RANDOM_COLOURS if is_random else ORACLE_COLOURS
    (pr, pc), (qr, qc) = world_to_pixel(pick[:2]), world_to_pixel(place[:2])
    turn = float(place[3] - pick[3])
    for dx in offsets:
        p = ((pc + 0.5) * SCALE + dx, (pr + 0.5) * SCALE)
        q = ((qc + 0.5) * SCALE + dx, (qr + 0.5) * SCALE)
        draw.line([p, q], fill=(255, 255, 255), width=1)
        r = 2 * SCALE
        draw.line([(p[0] - r, p[1] - r), (p[0] + r, p[1] + r)], fill=pick_c, width=2)
        draw.line([(p[0] - r, p[1] + r), (p[0] + r, p[1] - r)], fill=pick_c, width=2)
        draw.ellipse([q[0] - r, q[1] - r, q[0] + r, q[1] + r], outline=place_c, width=2)
        # Image angle == world yaw in (col, row); rows grow downwards on screen.
        tip = (q[0] + 3 * r * math.cos(turn), q[1] + 3 * r * math.sin(turn))
        draw.line([q, tip], fill=place_c, width=2)
    return np.asarray(img)


def _caption(image: np.ndarray, text: str) -> np.ndarray:

    bar = Image.new("RGB", (image.shape[1], 14), (255, 255, 255))
    ImageDraw.Draw(bar).text((4, 1), text, fill=(0, 0, 0))
    return np.concatenate([np.asarray(bar), image], axis=0)


def episode_frames(episode: Episode) -> list[np.ndarray]:
    """One picture per frame; frame ``t`` carries action ``t`` (the last frame, the goal, none)."""
    width = episode.color.shape[2]
    offsets = (0, (width + 4) * SCALE)
    frames = []
    for t in range(episode.n_steps + 1):
        img = _panel(episode.color[t], episode.height[t])
        if t < episode.n_steps:
            img = _draw_action(img, episode.pick[t], episode.place[t], bool(episode.random[t]), offsets)
            kind = "random" if episode.random[t] else "oracle"
            text = f"{episode.task} seed {episode.seed}  step {t}/{episode.n_steps}: {kind}"
        else:
            text = f"{episode.task} seed {episode.seed}  goal (frame {t})"
        frames.append(_caption(img, f"{text}  progress {episode.progress[t]:.0%}"))
    return frames


def save_episode_view(episode: Episode, out: str | Path, fps: float = 1.0) -> Path:
    """Write the episode as a GIF (one frame per step) or a PNG (all frames stacked downwards)."""

    out = Path(out)
    frames = episode_frames(episode)
    suffix = out.suffix.lower()
    if suffix == ".gif":
        save_gif(out, frames, fps=fps)
    elif suffix == ".png":
        gap = np.full((6, frames[0].shape[1], 3), 255, np.uint8)
        parts = [part for f in frames for part in (f, gap)][:-1]
        save_png(out, np.concatenate(parts, axis=0))
    else:
        raise DataError(f"{out}: the picture must end in .gif or .png")
    return out
