"""RGB-D views -> the top-down RGB-H image: the one fusion of tvf, for the simulator and for camera files.

A view is a colour image and a depth image of one calibrated camera (:class:`PinholeCamera`). Every
pixel is back-projected along its ray to a point in the robot base frame, the points are binned into
the workspace grid of :mod:`tvf.geometry` (floor rule, half-open bounds), and the views are fused: per
pixel the height is the highest point any view saw; the colour is the mean over the views whose own top
point reaches that height. :func:`fill_holes` gives pixels no view saw values from measured ones:
``nearest`` (the nearest measured pixel's) or ``background`` (the lowest surface on the hole's rim, which
is what a camera's occlusion shadow hides; the fill for one-camera rigs). :func:`level_on_table` corrects
a camera's pose on the table it sees before the fusion (the tilt and height of a calibration error).

Camera conventions (those of ROS ``sensor_msgs/CameraInfo`` and REP 103/104 optical frames):

* The camera frame is the **optical frame**: z forward along the optical axis, x right, y down in the
  image. The pose is ``T_base<-camera``: a point ``p_c`` in the camera frame is ``R p_c + t`` in the base.
* Pixel ``(row v, col u)`` with integer u, v looks along the ray through the image point (u, v):
  normalised coordinates ``((u - cx) / fx, (v - cy) / fy)``, OpenCV's rule (integers at pixel centres
  for a pixel-centre camera). The simulator's renderer samples elsewhere; its cameras carry that in
  cx, cy (``tvf.sim.camera.CameraConfig.pinhole``).
* Depth is the distance along the optical axis (the z of the point in the camera frame), in metres,
  as ROS depth images have it (not the distance along the ray). Depth <= 0 or not finite: no reading.
* Distortion is the 5-parameter ``plumb_bob`` model, ``D = (k1, k2, p1, p2, k3)``: each pixel's
  ray is found by inverting the model numerically (no image resampling); D = 0 is a pinhole.

Pure NumPy/SciPy: no renderer, no torch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from scipy import ndimage

from tvf.errors import TvfError
from tvf.geometry import WORKSPACE, Workspace, rotation_matrix, world_to_pixel

#: Points this far below the table (z_min) still count as table (depth noise is a few micrometres).
Z_TOLERANCE = 0.002
#: Views whose own top point is within this of the fused max contribute to a pixel's colour.
COLOR_HEIGHT_TOLERANCE = 0.005
#: ``background`` filling: rim pixels this close to the rim's lowest height count as the background.
BACKGROUND_TOLERANCE = 0.005
#: Fixed-point steps and the residual (normalised image units) of the distortion inversion.
UNDISTORT_STEPS = 100
UNDISTORT_TOLERANCE = 1e-10
#: Table levelling: points within this (m) of the table height are candidates for the table plane.
LEVEL_BAND = 0.02
#: Table levelling: the cap (m) on a point's distance in a plane's score (about 2 sigma of the D415's noise).
LEVEL_INLIER = 0.002
#: Table levelling: the least-squares refinement fits the points within this (m) of the plane.
LEVEL_REFINE = 0.003
#: Table levelling: planes through three random candidates, and how many candidates score them.
LEVEL_HYPOTHESES, LEVEL_SAMPLE = 64, 20_000
#: Table levelling: fewest table points a fit accepts (a camera sees tens of thousands).
LEVEL_MIN_POINTS = 2000

View = tuple[np.ndarray, np.ndarray]
"""One view: colour uint8 (H, W, 3) and depth (H, W) in metres along the optical axis."""


def _matrix_tuple(m: np.ndarray) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(float(v) for v in row) for row in np.asarray(m, dtype=np.float64))


@dataclass(frozen=True)
class PinholeCamera:
    """A calibrated camera: the intrinsics of ROS ``CameraInfo`` and the pose ``T_base<-camera``.

    ``rotation`` (3 x 3) and ``position`` (3) map the optical frame (z forward, x right, y down) into
    the robot base frame. Hashable (tuples), so rays are cached per camera.
    """

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    rotation: tuple[tuple[float, ...], ...]
    position: tuple[float, ...]
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    """plumb_bob ``(k1, k2, p1, p2, k3)``."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        for key in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, key, float(getattr(self, key)))
        object.__setattr__(self, "rotation", _matrix_tuple(self.rotation))
        object.__setattr__(self, "position", tuple(float(v) for v in self.position))
        object.__setattr__(self, "distortion", tuple(float(v) for v in self.distortion))

    @classmethod
    def from_matrices(
        cls, name: str, width: int, height: int, K: np.ndarray, T_base_camera: np.ndarray,
        distortion: Sequence[float] = (0.0,) * 5,
    ) -> PinholeCamera:  # fmt: skip
        """From a 3 x 3 ``K`` and a 4 x 4 ``T_base<-camera``."""
        K, T = np.asarray(K, dtype=np.float64), np.asarray(T_base_camera, dtype=np.float64)
        return cls(name, width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], T[:3, :3], T[:3, 3], distortion)

    @property
    def K(self) -> np.ndarray:
        """The 3 x 3 intrinsic matrix (``CameraInfo.K``, row-major)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def T_base_camera(self) -> np.ndarray:
        """The 4 x 4 pose of the optical frame in the robot base frame."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.rotation, self.position
        return T


# --------------------------------------------------------------------------------------------
# Distortion (plumb_bob)


def distort(x: np.ndarray, y: np.ndarray, d: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Normalised pinhole coordinates -> distorted ones under ``d = (k1, k2, p1, p2, k3)``."""
    radial, tx, ty = _distortion_terms(x, y, d)
    return x * radial + tx, y * radial + ty


def _distortion_terms(x: np.ndarray, y: np.ndarray, d: Sequence[float]):
    """The radial factor and the tangential shifts (x, y) of plumb_bob at (x, y)."""
    k1, k2, p1, p2, k3 = d
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return radial, 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x), p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y


def undistort(xd: np.ndarray, yd: np.ndarray, d: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Invert :func:`distort` by fixed-point iteration; coordinates it cannot invert come back NaN."""
    if len(d) != 5:
        raise ValueError(f"plumb_bob has 5 coefficients (k1, k2, p1, p2, k3), got {len(d)}")
    xd, yd = np.asarray(xd, dtype=np.float64), np.asarray(yd, dtype=np.float64)
    x, y = xd.copy(), yd.copy()
    with np.errstate(all="ignore"):  # a diverging pixel ends as inf/NaN and is reported as NaN
        for _ in range(UNDISTORT_STEPS):  # x = (x_d - tangential(x)) / radial(x), from x = x_d
            radial, tx, ty = _distortion_terms(x, y, d)
            x, y = (xd - tx) / radial, (yd - ty) / radial
        fx, fy = distort(x, y, d)
        bad = ~(np.hypot(fx - xd, fy - yd) < UNDISTORT_TOLERANCE)
    return np.where(bad, np.nan, x), np.where(bad, np.nan, y)


# --------------------------------------------------------------------------------------------
# Back-projection


@lru_cache(maxsize=32)
def pixel_rays(camera: PinholeCamera) -> np.ndarray:
    """Base-frame ray per pixel, row-major, scaled so that point = position + depth * ray; (3, H*W).

    The optical-frame ray of pixel (v, u) is ``(x, y, 1)`` with (x, y) its undistorted normalised
    coordinates, so ``depth`` (along the optical axis) scales it to the point. NaN where the distortion
    could not be inverted.
    """
    u = (np.arange(camera.width) - camera.cx) / camera.fx
    v = (np.arange(camera.height) - camera.cy) / camera.fy
    uu, vv = np.meshgrid(u, v)
    if any(camera.distortion):
        uu, vv = undistort(uu, vv, camera.distortion)
    rays = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)])
    out = np.ascontiguousarray(np.asarray(camera.rotation) @ rays)
    out.setflags(write=False)
    return out


def _depth_to_xyz(depth: np.ndarray, camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    d = np.asarray(depth, dtype=np.float64).ravel()
    d = np.where(np.isfinite(d) & (d > 0), d, np.nan)  # no reading -> a NaN point, dropped when binned
    rays = pixel_rays(camera)
    px, py, pz = camera.position
    return px + d * rays[0], py + d * rays[1], pz + d * rays[2]


def depth_to_points(depth: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    """Depth image (H, W) -> base-frame points (H*W, 3), row-major; NaN rows where there is no reading."""
    return np.stack(_depth_to_xyz(depth, camera), axis=-1)


# --------------------------------------------------------------------------------------------
# Binning and fusion


def bin_points(
    points: np.ndarray, colors: np.ndarray, workspace: Workspace = WORKSPACE, z_tolerance: float = Z_TOLERANCE
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Highest point per workspace pixel: height (rows, cols) float64 (NaN = empty), colour float64.

    Points outside ``[min, max)`` in x, y and outside ``[z_min - z_tolerance, z_max)`` (and NaN points)
    are dropped; pixels come from :func:`tvf.geometry.world_to_pixel` (floor). Colour is the mean colour
    of the points that reach the top height (ties are averaged, so the result does not depend on order).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return bin_xyz(pts[:, 0], pts[:, 1], pts[:, 2], colors, workspace, z_tolerance)


def bin_xyz(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, colors: np.ndarray, ws: Workspace = WORKSPACE,
    z_tolerance: float = Z_TOLERANCE,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """:func:`bin_points` on coordinate arrays."""
    keep = (
        (x >= ws.x_min) & (x < ws.x_max) & (y >= ws.y_min) & (y < ws.y_max)
        & (z >= ws.z_min - z_tolerance) & (z < ws.z_max)
    )  # fmt: skip
    idx = np.flatnonzero(keep)
    z = z[idx]
    rgb = np.asarray(colors).reshape(-1, 3)[idx]
    rc = world_to_pixel(np.stack([x[idx], y[idx]], axis=-1), ws)
    cell = rc[:, 0] * ws.cols + rc[:, 1]
    n_cells = ws.rows * ws.cols
    top = np.full(n_cells, -np.inf)
    np.maximum.at(top, cell, z)
    winner = z == top[cell]
    wcell = cell[winner]
    count = np.bincount(wcell, minlength=n_cells)
    wrgb = rgb[winner].astype(np.float64)
    color = np.stack([np.bincount(wcell, weights=wrgb[:, k], minlength=n_cells) for k in range(3)], axis=-1)
    color = color.astype(np.float64)  # bincount of no points is int64
    filled = count > 0
    color[filled] /= count[filled, None]
    height = np.where(filled, np.maximum(top - ws.z_min, 0.0), np.nan)
    return height.reshape(ws.shape), color.reshape(*ws.shape, 3)


def fuse_with_coverage(
    views: Sequence[View], cameras: Sequence[PinholeCamera], workspace: Workspace = WORKSPACE
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fuse RGB-D views without hole filling: colour uint8, height float32, covered mask (bool).

    Height is the per-pixel max over all views. Colour is the mean over the views whose top point at
    that pixel lies within :data:`COLOR_HEIGHT_TOLERANCE` of that max, so colour and height describe
    the same surface (averaging all views would blend a block's colour with the table at its edges).
    Empty pixels are 0.
    """
    if len(views) != len(cameras):
        raise ValueError(f"{len(views)} views but {len(cameras)} cameras")
    per_view = [
        bin_xyz(*_depth_to_xyz(depth, cam), rgb, workspace)
        for (rgb, depth), cam in zip(views, cameras, strict=True)
    ]
    heights = np.stack([h for h, _ in per_view])  # (V, rows, cols), NaN where empty
    colors = np.stack([c for _, c in per_view])
    covered = ~np.all(np.isnan(heights), axis=0)
    top = np.where(covered, np.where(np.isnan(heights), -np.inf, heights).max(axis=0), 0.0)
    near_top = heights >= top - COLOR_HEIGHT_TOLERANCE  # NaN compares False
    n = near_top.sum(axis=0)
    color = (colors * near_top[..., None]).sum(axis=0) / np.maximum(n, 1)[..., None]
    color_u8 = np.clip(np.rint(color), 0, 255).astype(np.uint8)
    return color_u8, top.astype(np.float32), covered


def fill_nearest(color: np.ndarray, height: np.ndarray, covered: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Give each uncovered pixel the colour and height of its nearest covered pixel."""
    if covered.all() or not covered.any():
        return color, height
    _, (ri, ci) = ndimage.distance_transform_edt(~covered, return_indices=True)
    return color[ri, ci], height[ri, ci]


def fill_background(
    color: np.ndarray, height: np.ndarray, covered: np.ndarray, tolerance: float = BACKGROUND_TOLERANCE
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Fill each hole (4-connected) from the lowest surface on its rim: its nearest rim pixel within
    ``tolerance`` of the rim's lowest height.

    A camera looking at an angle misses what an object hides behind it; the hidden pixels border the
    occluder (high) and the surface behind it (low), and the low one is what lies there. Nearest-pixel
    filling would extend the occluder into its shadow instead. A one-pixel hole takes its lowest covered
    4-neighbour.
    """
    if covered.all() or not covered.any():
        return color, height
    labels, n = ndimage.label(~covered)
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    color, height = _fill_single_pixels(color, height, covered, (labels > 0) & (sizes[labels] == 1))
    for index, box in enumerate(ndimage.find_objects(labels), start=1):
        if sizes[index] == 1:
            continue
        box = tuple(slice(max(s.start - 1, 0), s.stop + 1) for s in box)
        hole = labels[box] == index
        rim = ndimage.binary_dilation(hole) & covered[box]
        h, c = height[box], color[box]
        low = rim & (h <= h[rim].min() + tolerance)
        _, (ri, ci) = ndimage.distance_transform_edt(~low, return_indices=True)
        h[hole], c[hole] = h[ri, ci][hole], c[ri, ci][hole]
    return color, height


def _fill_single_pixels(
    color: np.ndarray, height: np.ndarray, covered: np.ndarray, single: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """:func:`fill_background` for one-pixel holes, at once: each takes its lowest covered 4-neighbour."""
    rows, cols = np.nonzero(single)
    padded = np.pad(np.where(covered, height, np.inf), 1, constant_values=np.inf)
    steps = np.array([(-1, 0), (1, 0), (0, -1), (0, 1)])
    nr, nc = rows[:, None] + steps[:, 0], cols[:, None] + steps[:, 1]  # (n, 4), unpadded indices
    best = np.argmin(padded[nr + 1, nc + 1], axis=1)
    r, c = nr[np.arange(len(rows)), best], nc[np.arange(len(rows)), best]
    color, height = color.copy(), height.copy()
    color[rows, cols], height[rows, cols] = color[r, c], height[r, c]
    return color, height


HOLE_FILLS = {"nearest": fill_nearest, "background": fill_background}
"""The hole fillings by name (:func:`fill_holes`)."""


def fill_holes(
    color: np.ndarray, height: np.ndarray, covered: np.ndarray, mode: str = "nearest"
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Give the pixels no view covered values from covered ones, by ``mode`` (:data:`HOLE_FILLS`)."""
    if mode not in HOLE_FILLS:
        raise ValueError(f"unknown hole filling {mode!r}; choose one of {', '.join(HOLE_FILLS)}")
    return HOLE_FILLS[mode](color, height, covered)


# --------------------------------------------------------------------------------------------
# Levelling a camera on the table


class TableLevelError(TvfError):
    """Too few table points in a view to level its camera."""


def table_plane(
    depth: np.ndarray, camera: PinholeCamera, workspace: Workspace = WORKSPACE
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The table as ``camera`` sees it: its unit normal (z up) and a point on it (base frame, m).

    The candidates are the points inside the workspace's x-y bounds within :data:`LEVEL_BAND` of the
    table height ``workspace.z_min``. Of :data:`LEVEL_HYPOTHESES` planes through three of them, the one
    they fit best is the table, not the base's top 5 mm above it nor a plane between the two (RANSAC
    with MSAC's score, :func:`_best_fitting_plane`; a fixed seed: the fit is a function of the image); a
    least-squares fit of ``z = a x + b y + c`` to the points within :data:`LEVEL_REFINE` of it, repeated once
    on the new fit's, refines it.
    """
    x, y, z = _depth_to_xyz(depth, camera)
    near = np.abs(z - workspace.z_min) < LEVEL_BAND  # NaN (no reading) fails every comparison
    near &= workspace.contains_xy(np.stack([x, y], axis=-1))
    _require_table_points(camera, int(near.sum()), LEVEL_BAND)
    centre = np.array([*workspace.center, workspace.z_min])
    points = np.stack([x[near], y[near], z[near]], axis=1) - centre
    normal, offset = _best_fitting_plane(points, np.random.default_rng(0))
    for _ in range(2):
        on = np.abs(points @ normal - offset) < LEVEL_REFINE
        _require_table_points(camera, int(on.sum()), LEVEL_REFINE)
        A = np.stack([points[on, 0], points[on, 1], np.ones(int(on.sum()))], axis=1)
        a, b, c = np.linalg.lstsq(A, points[on, 2], rcond=None)[0]
        normal = np.array([-a, -b, 1.0]) / math.hypot(a, b, 1.0)
        offset = c * normal[2]
    return normal, centre + [0.0, 0.0, offset / normal[2]]


def _best_fitting_plane(points: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Of planes through random triples of ``points``, the (unit normal, offset) the points fit best: the
    least sum of squared distances, each capped at :data:`LEVEL_INLIER` (MSAC's score, which a plane
    tilted to pass near both the table and the base's top loses to the table, unlike a count of points
    within the band)."""
    sample = points[rng.choice(len(points), min(len(points), LEVEL_SAMPLE), replace=False)]
    p0, p1, p2 = (sample[rng.integers(0, len(sample), LEVEL_HYPOTHESES)] for _ in range(3))
    normals = np.cross(p1 - p0, p2 - p0)
    normals *= np.sign(normals[:, 2:3]) + (normals[:, 2:3] == 0)  # z up
    length = np.linalg.norm(normals, axis=1)
    valid = length > 1e-9  # not three points on a line
    normals[valid] /= length[valid, None]
    offsets = np.einsum("hk,hk->h", normals, p0)
    cost = np.minimum(np.square(sample @ normals.T - offsets), LEVEL_INLIER**2).sum(axis=0)
    best = int(np.argmin(np.where(valid, cost, np.inf)))
    return normals[best], float(offsets[best])


def _require_table_points(camera: PinholeCamera, count: int, band: float) -> None:
    if count < LEVEL_MIN_POINTS:
        raise TableLevelError(
            f"camera {camera.name!r}: {count} points lie within {band * 1000:.0f} mm of the table plane, "
            f"fewer than {LEVEL_MIN_POINTS}; level only cameras that see the bare table inside the "
            "workspace, with a pose good to about 1 cm"
        )  # fmt: skip


def level_on_table(
    depth: np.ndarray, camera: PinholeCamera, workspace: Workspace = WORKSPACE
) -> PinholeCamera:  # fmt: skip
    """``camera`` with its pose corrected so the table it sees is level at ``workspace.z_min``.

    Turns the camera about its optical centre by the smallest rotation that makes the fitted table
    (:func:`table_plane`) horizontal, then moves it up or down to put the table at the table height: this
    corrects the two tilts and the height of a slightly wrong calibration. The turn about the vertical and
    the shift along the table are invisible in a plane and stay as they were (docs/real-robot.md).
    """
    normal, point = table_plane(depth, camera, workspace)
    axis = np.cross(normal, [0.0, 0.0, 1.0])  # |axis| = sin(angle between the normal and up)
    angle = float(np.arctan2(np.linalg.norm(axis), normal[2]))
    turn = rotation_matrix(axis / np.linalg.norm(axis) * angle) if angle > 0 else np.eye(3)
    origin = np.asarray(camera.position)
    lift = workspace.z_min - origin[2] - float(normal @ (point - origin))
    return replace(camera, rotation=turn @ np.asarray(camera.rotation), position=origin + [0.0, 0.0, lift])


def fuse(
    views: Sequence[View],
    cameras: Sequence[PinholeCamera],
    workspace: Workspace = WORKSPACE,
    fill: bool = False,
    hole_fill: str = "nearest",
) -> tuple[np.ndarray, np.ndarray]:
    """Fuse RGB-D ``views`` [(rgb, depth), ...] -> colour uint8 (rows, cols, 3), height float32; with
    ``fill``, holes filled by ``hole_fill`` (:data:`HOLE_FILLS`)."""
    color, height, covered = fuse_with_coverage(views, cameras, workspace)
    return fill_holes(color, height, covered, hole_fill) if fill else (color, height)
