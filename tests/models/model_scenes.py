"""Tiny synthetic top-down scenes for the model tests (no simulator needed)."""

from __future__ import annotations

import torch

from tvf.models.images import to_rgbh

BLOCK = 13  # pixels, about a 4 cm block at 3.125 mm per pixel
TABLE_COLOR = (50.0, 50.0, 50.0)
BLOCK_COLOR = (255.0, 87.0, 89.0)
BLOCK_HEIGHT = 0.04


def draw_blocks(centres: list[tuple[int, int]], size: int = 160) -> tuple[torch.Tensor, torch.Tensor]:
    """Colour (H, W, 3) float and height (H, W) metres with axis-aligned 13 x 13 blocks at ``centres``."""
    color = torch.tensor(TABLE_COLOR).expand(size, size, 3).clone()
    height = torch.zeros(size, size)
    half = BLOCK // 2
    for r, c in centres:
        color[r - half : r + half + 1, c - half : c + half + 1] = torch.tensor(BLOCK_COLOR)
        height[r - half : r + half + 1, c - half : c + half + 1] = BLOCK_HEIGHT
    return color, height


def pick_place_batch(batch: int, generator: torch.Generator, n_blocks: int = 3) -> dict[str, torch.Tensor]:
    """Scenes where block 0 moves to a free spot: current, goal = next RGB-H and the action labels."""
    current, goal, picks, places = [], [], [], []
    for _ in range(batch):
        centres = torch.randint(20, 140, (n_blocks + 1, 2), generator=generator).tolist()
        blocks, target = centres[:n_blocks], centres[n_blocks]
        current.append(to_rgbh(*draw_blocks([tuple(b) for b in blocks])))
        goal.append(to_rgbh(*draw_blocks([tuple(target)] + [tuple(b) for b in blocks[1:]])))
        picks.append(blocks[0])
        places.append(target)
    return {
        "current": torch.cat(current),
        "goal": torch.cat(goal),
        "pick": torch.tensor(picks),
        "place": torch.tensor(places),
        "rot": torch.randint(0, 36, (batch,), generator=generator),
    }
