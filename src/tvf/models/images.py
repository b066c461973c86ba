"""RGB-H image tensors for the networks: stacking, normalisation and its inverse.

Models take *normalised RGB-H* tensors ``(B, 4, H, W)`` float32: channels R, G, B, H with

* colour ``(c / 255 - COLOR_MEAN) / COLOR_STD`` and
* height ``(h - HEIGHT_MEAN) / HEIGHT_STD`` (h in metres above the table),

the constants of the reference (Ravens). Zero therefore means "mean value", not "empty table".
"""

from __future__ import annotations

import numpy as np
import torch

COLOR_MEAN = 0.18877631
COLOR_STD = 0.07276466
HEIGHT_MEAN = 0.00509261
HEIGHT_STD = 0.00903967
MAX_HEIGHT = 0.28  # workspace z range in metres
RGBH_CHANNELS = 4
HEIGHT_CHANNEL = RGBH_CHANNELS - 1
"""The index of height in an RGB-H tensor's channels."""

ArrayLike = torch.Tensor | np.ndarray


def to_rgbh(color: ArrayLike, height: ArrayLike) -> torch.Tensor:
    """``color`` (B, H, W, 3) uint8 or float in 0..255 and ``height`` (B, H, W) metres -> normalised RGB-H.

    Unbatched inputs ((H, W, 3) and (H, W)) give a batch of one. Returns (B, 4, H, W) float32.
    """
    c = torch.as_tensor(color).to(torch.float32)
    h = torch.as_tensor(height).to(torch.float32)
    if c.dim() == 3:
        c, h = c.unsqueeze(0), h.unsqueeze(0)
    if c.shape[-1] != 3 or c.shape[:-1] != h.shape:
        raise ValueError(
            f"expected color (B,H,W,3) and height (B,H,W), got {tuple(c.shape)}, {tuple(h.shape)}"
        )
    c = (c / 255.0 - COLOR_MEAN) / COLOR_STD
    h = normalised_heights(h)
    return torch.cat([c.permute(0, 3, 1, 2), h.unsqueeze(1)], dim=1).contiguous()


def from_rgbh(rgbh: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised RGB-H (B, 4, H, W) -> (colour (B, H, W, 3) float 0..255, height (B, H, W) metres).

    No clamping; see :func:`clamp_rgbh`.
    """
    color = (rgbh[:, :3] * COLOR_STD + COLOR_MEAN) * 255.0
    return color.permute(0, 2, 3, 1).contiguous(), heights_of(rgbh).contiguous()


def normalised_heights(metres: torch.Tensor) -> torch.Tensor:
    """Heights in metres (any shape) as the normalised RGB-H height channel (:func:`heights_of` inverts
    it)."""
    return (metres - HEIGHT_MEAN) / HEIGHT_STD


def heights_of(rgbh: torch.Tensor) -> torch.Tensor:
    """Metres (B, H, W) of normalised RGB-H images (B, 4, H, W)."""
    return rgbh[:, HEIGHT_CHANNEL] * HEIGHT_STD + HEIGHT_MEAN


def _normalised_bounds(device: torch.device | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    low = torch.tensor([-COLOR_MEAN / COLOR_STD] * 3 + [-HEIGHT_MEAN / HEIGHT_STD], device=device)
    high = torch.tensor(
        [(1.0 - COLOR_MEAN) / COLOR_STD] * 3 + [(MAX_HEIGHT - HEIGHT_MEAN) / HEIGHT_STD], device=device
    )
    return low.view(1, 4, 1, 1), high.view(1, 4, 1, 1)


def clamp_rgbh(rgbh: torch.Tensor) -> torch.Tensor:
    """Clamp normalised RGB-H to physical ranges: colour 0..255, height 0..MAX_HEIGHT metres."""
    low, high = _normalised_bounds(rgbh.device)
    return torch.maximum(torch.minimum(rgbh, high.to(rgbh.dtype)), low.to(rgbh.dtype))


def as_pixels(pixels: ArrayLike, batch: int, shape: tuple[int, int] | None = None) -> torch.Tensor:
    """Integer (row, col) pixels as a (B, 2) int64 tensor (a single (2,) pixel is broadcast to B).

    Float pixels are refused: rounding belongs to :mod:`tvf.geometry` (``world_to_pixel``). With
    ``shape`` (H, W), pixels outside the image raise ``ValueError``.
    """
    p = torch.as_tensor(pixels)
    if p.dtype.is_floating_point or p.dtype.is_complex or p.dtype == torch.bool:
        raise ValueError(f"pixels must be integers (use tvf.geometry.world_to_pixel), got {p.dtype}")
    p = p.to(torch.int64)
    if p.dim() == 1:
        p = p.unsqueeze(0).expand(batch, 2)
    if p.shape != (batch, 2):
        raise ValueError(f"expected pixels of shape ({batch}, 2), got {tuple(p.shape)}")
    if shape is not None:
        inside = (p >= 0).all(dim=1) & (p[:, 0] < shape[0]) & (p[:, 1] < shape[1])
        if not bool(inside.all()):
            raise ValueError(f"pixels outside the {shape[0]} x {shape[1]} image: {p[~inside].tolist()}")
    return p
