"""Picks moved to the middle of the picked block's top face (``--centre-picks``).

The GCTN places the suction point: a block picked off its middle lands off its target by the pick's
offset. The expert's demonstrations pick a median 2.25 px (p90 3.8 px) off the face's centre
(docs/results.md, "Centring the block, not the suction point"), so the GCTN learned to pick off centre
too, and a place rule that centres the place pixel (the goal mask's ``centred`` places) then centres the
suction point, not the block. :class:`CentredPickGCTN` moves every pick the GCTN chooses, in the greedy
action and in the search, to the centre of the top face under it, read from the current height map: the
connected pixels within :data:`FACE_TOLERANCE` of the pick's height. The transport's crop is then centred
on the block, so its place is where the block's middle goes. Where the reading is not one block's face
(too small, too large, or running out of the window, e.g. a pick on the table or on merged faces), the
pick stays where the GCTN put it. Batched over every pick, no training.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from tvf.geometry import PIXEL_SIZE
from tvf.models.gctn import GctnWrapper
from tvf.models.images import heights_of
from tvf.tasks import BLOCK_SIZE

FACE_TOLERANCE = 0.005
"""Metres: pixels this close to the height at the pick and connected to it belong to its top face."""
FACE_WINDOW = 31
"""Pixels: the square searched around the pick (a 4 cm block is about 13 px across)."""
FACE_AREA = (BLOCK_SIZE / PIXEL_SIZE) ** 2
"""Pixels of one block's top face (about 164)."""
FACE_AREA_RANGE = (0.35 * FACE_AREA, 1.6 * FACE_AREA)
"""Readings outside this many pixels are not one block's face (partly hidden, or merged with others)."""

_CROSS = torch.tensor([[0.0, 1.0, 0.0], [1.0, 1.0, 1.0], [0.0, 1.0, 0.0]]).view(1, 1, 3, 3)


def _windows(height: torch.Tensor, picks: torch.Tensor, window: int) -> torch.Tensor:
    """The ``window`` squares (N, window, window) of ``height`` (B, H, W) around ``picks`` (B, P, 2),
    NaN beyond the image."""
    b, p = picks.shape[:2]
    half = window // 2
    padded = F.pad(height, (half, half, half, half), value=float("nan"))
    offsets = torch.arange(window, device=height.device)
    rows = picks[..., 0].reshape(-1, 1) + offsets  # padded coordinates of each window's rows
    cols = picks[..., 1].reshape(-1, 1) + offsets
    batch = torch.arange(b, device=height.device).repeat_interleave(p)
    return padded[batch[:, None, None], rows[:, :, None], cols[:, None, :]]


def _grow(seed: torch.Tensor, inside: torch.Tensor) -> torch.Tensor:
    """The pixels of ``inside`` (N, S, S) connected (4-neighbours) to ``seed`` (N, S, S), both bool."""
    kernel = _CROSS.to(inside.device)
    region = seed & inside
    for _ in range(inside.shape[-1] * inside.shape[-2]):
        grown = (F.conv2d(region[:, None].float(), kernel, padding=1)[:, 0] > 0) & inside
        if torch.equal(grown, region):
            break
        region = grown
    return region


def face_centres(height: torch.Tensor, picks: torch.Tensor, window: int = FACE_WINDOW) -> torch.Tensor:
    """``picks`` (B, P, 2) (row, col) moved to the centre of the top face under each, read from
    ``height`` (B, H, W, metres); a pick whose face is not one block's stays."""
    picks = torch.as_tensor(picks, dtype=torch.int64, device=height.device)
    if picks.numel() == 0:
        return picks
    half = window // 2
    patches = _windows(height.float(), picks, window)
    level = patches[:, half, half]
    near = (patches - level[:, None, None]).abs() <= FACE_TOLERANCE  # NaN (off the image) is never near
    seed = torch.zeros_like(near)
    seed[:, half, half] = True
    face = _grow(seed, near)
    area = face.sum(dim=(1, 2))
    rim = face[:, 0].any(1) | face[:, -1].any(1) | face[:, :, 0].any(1) | face[:, :, -1].any(1)
    one_block = (area >= FACE_AREA_RANGE[0]) & (area <= FACE_AREA_RANGE[1]) & ~rim
    offsets = torch.arange(window, device=height.device, dtype=torch.float32) - half
    weights = face.float() / area.clamp(min=1).view(-1, 1, 1)
    shift = (
        torch.stack([(weights.sum(2) * offsets).sum(1), (weights.sum(1) * offsets).sum(1)], dim=1)
        .round()
        .to(torch.int64)
    )
    shift = torch.where(one_block[:, None], shift, torch.zeros_like(shift))
    size = torch.tensor(height.shape[-2:], device=height.device)
    moved = picks.reshape(-1, 2) + shift
    return torch.minimum(moved.clamp(min=0), size - 1).reshape(picks.shape)


class CentredPickGCTN(GctnWrapper):
    """A GCTN whose chosen picks move to the centre of the block face under them (:func:`face_centres`);
    its maps are the wrapped GCTN's (:class:`~tvf.models.gctn.GctnWrapper`'s)."""

    def pick_pixels(self, current: torch.Tensor, picks: torch.Tensor) -> torch.Tensor:
        """``picks`` (B, P, 2) of ``current`` moved to their blocks' face centres."""
        return face_centres(heights_of(current), self.gctn.pick_pixels(current, picks))


def centring_picks(gctn, centre: bool):
    """``gctn`` wrapped in :class:`CentredPickGCTN` when ``centre``, else itself."""
    return CentredPickGCTN(gctn) if centre else gctn
