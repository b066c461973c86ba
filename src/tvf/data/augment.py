"""One SE(2) augmentation for both samplers: turn and shift images and actions together.

The transform moves image content by ``p' = R(yaw) (p - c) + c + shift`` in the sub-pixel frame of
:mod:`tvf.data.format` (integer coordinates are pixel centres; ``c`` is the image centre (79.5, 79.5)),
written (row, col) and turned with :func:`tvf.geometry.rotate_pixels`, so an image turn by ``yaw`` is
a world turn by ``yaw`` (no sign flip). Images are warped with :func:`tvf.geometry.warp_images`
(nearest neighbour, zero outside: colour black, height 0). Key points are moved as sub-pixel points
and then rounded to the pixel that contains them. A pick-and-place's rotation (place yaw minus pick
yaw) is unchanged, because turning the whole scene turns the block and its target alike.

Distribution (facts §5): yaw ~ N(0, 60 degrees), shift ~ N(0, 160/6 px) per axis, resampled until
every key point (and, with ``margin``, the points ``margin`` pixels away along rows and columns)
stays inside the image; after ``max_tries`` rejected draws the sample is left untransformed.

Mirror images (the GCTN's ``--mirror``, off by default): a drawn share of the samples is reflected
left-right before its turn. A reflection reverses the sense of every turn, so a mirrored sample's
rotation label is the negated one (:class:`tvf.data.samplers.GctnSampler`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from tvf.data.format import subpixel_to_pixel
from tvf.geometry import WORKSPACE, rotate_pixels, se2_output_to_input, warp_images

ROTATION_STD = 2 * math.pi / 6
"""Standard deviation of the augmentation's turn (rad): 60 degrees."""
SHIFT_STD = WORKSPACE.rows / 6
"""Standard deviation of the augmentation's shift per axis (pixels): 26.7."""
IMAGE_CENTER = np.array([(WORKSPACE.rows - 1) / 2, (WORKSPACE.cols - 1) / 2])
"""Centre of the image in the sub-pixel frame (row, col)."""
MAX_TRIES = 100


@dataclass(frozen=True)
class Se2:
    """A batch of transforms: ``yaw`` (B,) radians and ``shift`` (B, 2) pixels as (row, col); with
    ``mirror`` (B,) bool, the flagged samples are first mirrored left-right (columns reversed about the
    image centre), so their transform is a reflection, then the turn and the shift."""

    yaw: np.ndarray
    shift: np.ndarray
    mirror: np.ndarray | None = None

    @staticmethod
    def identity(batch: int) -> Se2:
        return Se2(np.zeros(batch), np.zeros((batch, 2)))

    def __len__(self) -> int:
        return len(self.yaw)

    def mirrored(self) -> np.ndarray:
        """(B,) bool: which samples are mirrored (none without ``mirror``)."""
        return np.zeros(len(self), bool) if self.mirror is None else np.asarray(self.mirror, bool)

    def subset(self, part: slice) -> Se2:
        """The transforms of the samples ``part``."""
        mirror = None if self.mirror is None else self.mirror[part]
        return Se2(self.yaw[part], self.shift[part], mirror)


def mirror_points(points: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """Reflect the flagged samples' sub-pixel points ``(B, K, 2)`` left-right about the image centre."""
    points = np.array(points, dtype=np.float64)
    points[mirror, :, 1] = 2 * IMAGE_CENTER[1] - points[mirror, :, 1]
    return points


def transform_points(points: np.ndarray, se2: Se2) -> np.ndarray:
    """Move sub-pixel points ``(B, K, 2)`` (row, col) by each sample's transform."""
    points = mirror_points(points, se2.mirrored())
    turned = rotate_pixels(points, se2.yaw[:, None], IMAGE_CENTER)
    return turned + se2.shift[:, None, :]


def transform_pixels(pixels: np.ndarray, se2: Se2) -> np.ndarray:
    """Move integer pixels ``(B, K, 2)`` (their centres) and round to the containing pixel."""
    return subpixel_to_pixel(transform_points(pixels, se2))


def probe_points(points: np.ndarray, margin: float) -> np.ndarray:
    """The key points plus, if ``margin`` > 0, the four points ``margin`` px away along rows and cols."""
    points = np.asarray(points, dtype=np.float64)
    if margin <= 0:
        return points
    offsets = np.array([[0, 0], [margin, 0], [-margin, 0], [0, margin], [0, -margin]], dtype=np.float64)
    b, k, _ = points.shape
    return (points[:, :, None, :] + offsets[None, None]).reshape(b, k * len(offsets), 2)


def inside(points: np.ndarray) -> np.ndarray:
    """Per sample, whether every sub-pixel point ``(B, K, 2)`` rounds to a pixel inside the image."""
    px = subpixel_to_pixel(points)
    ok = (px[..., 0] >= 0) & (px[..., 0] < WORKSPACE.rows) & (px[..., 1] >= 0) & (px[..., 1] < WORKSPACE.cols)
    return ok.all(axis=-1)


def sample_se2(
    points: np.ndarray,
    rng: np.random.Generator,
    margin: float = 0.0,
    rotation_std: float = ROTATION_STD,
    shift_std: float = SHIFT_STD,
    max_tries: int = MAX_TRIES,
    mirror: float = 0.0,
) -> Se2:
    """Draw one transform per sample that keeps its key points ``(B, K, 2)`` inside the image; with
    ``mirror`` > 0, that share of the samples is mirrored first (drawn before the turns; at 0 nothing is
    drawn for it, so the stream of draws is the unmirrored one)."""
    flags = rng.random(len(points)) < mirror if mirror > 0 else None
    if flags is not None:
        points = mirror_points(points, flags)
    probes = probe_points(points, margin)
    b = probes.shape[0]
    yaw = np.zeros(b)
    shift = np.zeros((b, 2))
    todo = np.arange(b)
    for _ in range(max_tries):
        if not len(todo):
            break
        cand = Se2(rng.normal(0.0, rotation_std, len(todo)), rng.normal(0.0, shift_std, (len(todo), 2)))
        ok = inside(transform_points(probes[todo], cand))
        yaw[todo[ok]] = cand.yaw[ok]
        shift[todo[ok]] = cand.shift[ok]
        todo = todo[~ok]
    return Se2(yaw, shift, flags)  # samples still in ``todo`` keep no turn and no shift


def warp(images: torch.Tensor, se2: Se2) -> torch.Tensor:
    """Warp images ``(B, C, H, W)`` by each sample's transform (nearest neighbour, zero fill)."""
    b = images.shape[0]
    mirror = se2.mirrored()
    if mirror.any():
        flagged = torch.from_numpy(mirror)
        images = torch.where(flagged[:, None, None, None], images.flip(-1), images)
    if not np.any(se2.yaw) and not np.any(se2.shift):
        return images
    center = torch.as_tensor(np.broadcast_to(IMAGE_CENTER, (b, 2)).copy(), dtype=torch.float32)
    maps = se2_output_to_input(
        torch.as_tensor(se2.yaw, dtype=torch.float32), center, torch.as_tensor(se2.shift, dtype=torch.float32)
    )
    return warp_images(images, maps, mode="nearest")
