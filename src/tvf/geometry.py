"""The one coordinate contract of tvf: pixels <-> world, image angles <-> yaw.

Every other module converts through these functions; nothing else does its own rounding.

Conventions (see docs/conventions.md):

* The workspace is x in [0.25, 0.75], y in [-0.25, 0.25], z in [0, 0.28] metres, imaged top-down at
  3.125 mm per pixel, giving 160 x 160 images.
* A pixel is ``(row, col)``. Rows go with world **y** (row 0 is y = -0.25), columns with world **x**
  (col 0 is x = 0.25). Pixel ``(r, c)`` covers ``[x_min + c*s, x_min + (c+1)*s) x [y_min + r*s, ...)``;
  its world position is its **centre**. World -> pixel uses **floor**, the only rounding rule, so
  ``world_to_pixel(pixel_to_world(p)) == p`` exactly.
* Heights are metres above the table (z - z_min).
* Scenes are laid out inside the workspace shrunk by ``EDGE_MARGIN`` and inside the ``REACH`` ring
  around the robot base (the world origin); task files are checked against both and the height range.
* Yaw is the world rotation about +z, counter-clockwise seen from above. Because ``(col, row)``
  follows ``(x, y)``, a world yaw ``psi`` turns pixel coordinates ``(col, row)`` by the same matrix
  ``[[cos, -sin], [sin, cos]]``. (On a screen, where rows grow downwards, that looks clockwise.)
  The image angle of a rotation therefore *equals* the world yaw: there is no sign flip.
* Rotation bin ``i`` of ``R`` stands for yaw ``i * 2*pi / R``; ``yaw_to_bin`` rounds to the nearest bin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch

PIXEL_SIZE = 0.003125


@dataclass(frozen=True)
class Workspace:
    """Axis-aligned workspace imaged by the top-down height map."""

    x_min: float = 0.25
    x_max: float = 0.75
    y_min: float = -0.25
    y_max: float = 0.25
    z_min: float = 0.0
    z_max: float = 0.28
    pixel_size: float = PIXEL_SIZE

    @property
    def rows(self) -> int:
        """Image height in pixels (along y)."""
        return int(round((self.y_max - self.y_min) / self.pixel_size))

    @property
    def cols(self) -> int:
        """Image width in pixels (along x)."""
        return int(round((self.x_max - self.x_min) / self.pixel_size))

    @property
    def shape(self) -> tuple[int, int]:
        return (self.rows, self.cols)

    @property
    def center(self) -> tuple[float, float]:
        return (0.5 * (self.x_min + self.x_max), 0.5 * (self.y_min + self.y_max))

    def contains_xy(self, xy: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Whether points ``(..., 2)`` lie inside the workspace shrunk by ``margin`` metres."""
        xy = np.asarray(xy, dtype=np.float64)
        return (
            (xy[..., 0] >= self.x_min + margin)
            & (xy[..., 0] < self.x_max - margin)
            & (xy[..., 1] >= self.y_min + margin)
            & (xy[..., 1] < self.y_max - margin)
        )

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


WORKSPACE = Workspace()

REACH = (0.30, 0.72)
"""The ring (m from the robot base at the world origin) in which the arm reaches the table: every base
cell, block and target of a scene lies inside it."""
EDGE_MARGIN = 0.02
"""Every base cell, block and target of a scene keeps this far (m) inside the workspace edges."""


def world_to_pixel(xy: np.ndarray, ws: Workspace = WORKSPACE) -> np.ndarray:
    """World ``(..., 2)`` x, y in metres -> integer pixels ``(..., 2)`` as (row, col), by floor."""
    xy = np.asarray(xy, dtype=np.float64)
    col = np.floor((xy[..., 0] - ws.x_min) / ws.pixel_size)
    row = np.floor((xy[..., 1] - ws.y_min) / ws.pixel_size)
    # A point a hair below the upper bound can round onto the bound: keep it in the last pixel.
    col = np.where((col == ws.cols) & (xy[..., 0] < ws.x_max), ws.cols - 1, col)
    row = np.where((row == ws.rows) & (xy[..., 1] < ws.y_max), ws.rows - 1, row)
    return np.stack([row, col], axis=-1).astype(np.int64)


def pixel_to_world(rowcol: np.ndarray, ws: Workspace = WORKSPACE) -> np.ndarray:
    """Pixels ``(..., 2)`` as (row, col), integer or sub-pixel -> world x, y of the pixel centre."""
    rc = np.asarray(rowcol, dtype=np.float64)
    x = ws.x_min + (rc[..., 1] + 0.5) * ws.pixel_size
    y = ws.y_min + (rc[..., 0] + 0.5) * ws.pixel_size
    return np.stack([x, y], axis=-1)


def pixel_in_image(rowcol: np.ndarray, ws: Workspace = WORKSPACE) -> np.ndarray:
    """Whether integer pixels ``(..., 2)`` lie inside the image."""
    rc = np.asarray(rowcol)
    return (rc[..., 0] >= 0) & (rc[..., 0] < ws.rows) & (rc[..., 1] >= 0) & (rc[..., 1] < ws.cols)


def wrap_angle(angle: np.ndarray | float) -> np.ndarray | float:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(angle) + math.pi) % (2 * math.pi) - math.pi


def wrap_symmetric(angle: np.ndarray | float, period: float) -> np.ndarray | float:
    """Wrap angles to [-period/2, period/2) (e.g. a block's yaw modulo its 90 degree symmetry)."""
    return (np.asarray(angle) + period / 2) % period - period / 2


def yaw_to_bin(yaw: np.ndarray | float, n_rotations: int) -> np.ndarray:
    """World yaw -> nearest rotation bin in [0, n_rotations)."""
    step = 2 * math.pi / n_rotations
    return np.round(np.asarray(yaw, dtype=np.float64) / step).astype(np.int64) % n_rotations


def bin_to_yaw(index: np.ndarray | int, n_rotations: int) -> np.ndarray:
    """Rotation bin -> world yaw in [-pi, pi)."""
    return wrap_angle(np.asarray(index, dtype=np.float64) * (2 * math.pi / n_rotations))


def rotation_matrix(rotvec: np.ndarray | tuple[float, float, float]) -> np.ndarray:
    """The 3 x 3 rotation of angle ``|rotvec|`` (radians) about the axis ``rotvec`` (Rodrigues' formula)."""
    v = np.asarray(rotvec, dtype=np.float64)
    angle = float(np.linalg.norm(v))
    if angle == 0.0:
        return np.eye(3)
    k = v / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


def rotate_xy(xy: np.ndarray, yaw: np.ndarray | float) -> np.ndarray:
    """Rotate world vectors ``(..., 2)`` counter-clockwise by ``yaw``."""
    xy = np.asarray(xy, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * xy[..., 0] - s * xy[..., 1], s * xy[..., 0] + c * xy[..., 1]], axis=-1)


def rotate_pixels(rowcol: np.ndarray, yaw: np.ndarray | float, center: np.ndarray) -> np.ndarray:
    """Turn sub-pixel points ``(..., 2)`` (row, col) about ``center`` by the world yaw ``yaw``.

    This is the pixel-space image of :func:`rotate_xy`: ``pixel_to_world`` commutes with it.
    """
    rc = np.asarray(rowcol, dtype=np.float64) - np.asarray(center, dtype=np.float64)
    colrow = rotate_xy(rc[..., ::-1], yaw)
    return colrow[..., ::-1] + np.asarray(center, dtype=np.float64)


def quarter_turn_pixels(rowcol: np.ndarray, turns: int, size: int) -> np.ndarray:
    """Where integer pixels ``(..., 2)`` of a ``size`` x ``size`` image go under ``np.rot90(image, turns)``
    (``torch.rot90(x, turns, dims=(-2, -1))``): one turn sends ``(r, c)`` to ``(size - 1 - c, r)``.

    In the world that is a turn of the scene by yaw ``-turns * 90`` degrees about the image centre.
    """
    rc = np.asarray(rowcol)
    for _ in range(turns % 4):
        rc = np.stack([size - 1 - rc[..., 1], rc[..., 0]], axis=-1)
    return rc


def mirror_pixels(rowcol: np.ndarray, size: int) -> np.ndarray:
    """Where integer pixels ``(..., 2)`` of a ``size``-wide image go under ``np.flip(image, axis=-1)``
    (``torch.flip(x, dims=(-1,))``): ``(r, c)`` goes to ``(r, size - 1 - c)``, its own inverse.

    In the world that is the mirror image of the scene in the line through the image centre along the
    rows; it turns every yaw ``theta`` into ``-theta``.
    """
    rc = np.asarray(rowcol)
    return np.stack([rc[..., 0], size - 1 - rc[..., 1]], axis=-1)


def heights_from_z(z: np.ndarray, ws: Workspace = WORKSPACE) -> np.ndarray:
    """World z -> height above the table in metres."""
    return np.asarray(z) - ws.z_min


# --------------------------------------------------------------------------------------------
# Batched image warps on tensors (torch is imported lazily so the simulator does not need it).


def se2_output_to_input(
    yaw: torch.Tensor, center: torch.Tensor, shift: torch.Tensor | None = None
) -> torch.Tensor:
    """Pixel-space maps ``(N, 2, 3)`` for warps that turn image content by ``yaw`` about ``center``.

    The forward motion of content is ``p' = R(yaw) (p - center) + center + shift`` with pixel
    points written ``(col, row)``; the returned matrices map *output* pixels back to *input*
    pixels (what a sampler needs). ``center`` and ``shift`` are ``(N, 2)`` as (row, col).
    """
    import torch  # lazy: the geometry contract serves torch-free code (the simulator) too

    yaw = torch.as_tensor(yaw, dtype=torch.float32)
    n = yaw.shape[0]
    center_cr = torch.as_tensor(center, dtype=torch.float32).flip(-1)
    shift_cr = torch.zeros(n, 2) if shift is None else torch.as_tensor(shift, dtype=torch.float32).flip(-1)
    c, s = torch.cos(yaw), torch.sin(yaw)
    inv = torch.stack([torch.stack([c, s], -1), torch.stack([-s, c], -1)], -2)  # R(-yaw)
    offset = center_cr - (inv @ (center_cr + shift_cr).unsqueeze(-1)).squeeze(-1)
    return torch.cat([inv, offset.unsqueeze(-1)], dim=-1)


def warp_images(images: torch.Tensor, out_to_in: torch.Tensor, mode: str = "nearest") -> torch.Tensor:
    """Warp ``(N, C, H, W)`` images with pixel-space output->input maps ``(N, 2, 3)`` in (col, row).

    Pixels sampled from outside the input are zero.
    """
    import torch  # lazy, as above
    import torch.nn.functional as F

    n, _, h, w = images.shape
    m = out_to_in.to(images.device, torch.float32)
    scale = torch.tensor([2.0 / w, 2.0 / h], device=images.device)
    offset = torch.tensor([1.0 / w - 1.0, 1.0 / h - 1.0], device=images.device)
    # normalised n = scale * p + offset  =>  p = (n - offset) / scale
    lin = scale[:, None] * m[:, :, :2] / scale[None, :]
    trans = scale * m[:, :, 2] + offset - (lin @ offset[:, None]).squeeze(-1)
    theta = torch.cat([lin, trans.unsqueeze(-1)], dim=-1).to(images.dtype)
    grid = F.affine_grid(theta, [n, 1, h, w], align_corners=False)
    return F.grid_sample(images, grid, mode=mode, padding_mode="zeros", align_corners=False)
