"""Turning observations into pictures: height colour maps, side-by-side panels, atomic PNG writes."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
from matplotlib import colormaps

from tvf.io import atomic_write_bytes

HEIGHT_DISPLAY_MAX = 0.14
"""Heights (m) at or above this get the top colour of the map (a 3-layer structure is 0.125 m)."""


def height_to_rgb(height: np.ndarray, vmax: float = HEIGHT_DISPLAY_MAX) -> np.ndarray:
    """Height map (m) -> uint8 RGB with matplotlib's viridis."""
    x = np.clip(np.asarray(height, dtype=np.float64) / vmax, 0.0, 1.0)
    return (colormaps["viridis"](x)[..., :3] * 255).astype(np.uint8)


def side_by_side(*images: np.ndarray, gap: int = 4) -> np.ndarray:
    """Concatenate uint8 RGB images of equal height with a white gap."""
    h = images[0].shape[0]
    spacer = np.full((h, gap, 3), 255, np.uint8)
    parts: list[np.ndarray] = []
    for i, img in enumerate(images):
        if i:
            parts.append(spacer)
        parts.append(img)
    return np.concatenate(parts, axis=1)


def observation_panel(color: np.ndarray, height: np.ndarray, scale: int = 2) -> np.ndarray:
    """Colour and height side by side, enlarged ``scale`` times (nearest)."""
    panel = side_by_side(color, height_to_rgb(height))
    return panel.repeat(scale, 0).repeat(scale, 1)


def save_png(path: str | Path, image: np.ndarray) -> None:
    atomic_write_bytes(path, iio.imwrite("<bytes>", np.asarray(image, dtype=np.uint8), extension=".png"))


def save_gif(path: str | Path, frames: list[np.ndarray], fps: float = 1.0, hold_last: float = 1.0) -> None:
    """Write frames of equal size as a looping GIF, atomically; the last shows ``hold_last`` times as long."""
    durations = [1000 / fps] * len(frames)
    durations[-1] *= hold_last
    data = iio.imwrite(
        "<bytes>", np.stack(frames).astype(np.uint8), extension=".gif", duration=durations, loop=0
    )
    atomic_write_bytes(path, data)
