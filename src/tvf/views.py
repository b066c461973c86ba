"""Camera files: calibrated RGB-D views on disk -> the top-down RGB-H image the planners take.

A views folder (docs/real-robot.md) holds, per camera ``NAME``:

* ``NAME.yaml`` (or ``.yml``, ``.json``): the camera file, the intrinsics as ROS ``sensor_msgs/CameraInfo``
  has them and the pose ``T_base<-camera`` of the camera's optical frame;
* ``NAME.color.png``: 8-bit RGB (an alpha channel is dropped);
* ``NAME.depth.png`` (16-bit, times ``depth_scale`` metres per unit, 0.001 by default as in ROS REP 118)
  or ``NAME.depth.npy`` (float metres); depth along the optical axis, registered to the colour image;
  0 or NaN means no reading;

and optionally ``workspace.yaml`` (or ``.json``): the workspace bounds and pixel size in the base frame
(defaults: :data:`tvf.geometry.WORKSPACE`). The views are fused by :mod:`tvf.fusion`, the simulator's
own fusion, and holes are filled as the simulator fills them (``auto``: from the nearest measured pixel
with several views, from the lowest surface on a hole's rim with one, :func:`resolve_hole_fill`). A
saved RGB-H image is an ``.npz`` with ``color`` (uint8 rows x cols x 3) and ``height`` (float32 metres
above the table), what ``tvf render`` writes. Every bad file is a one-line :class:`TvfError` naming the
file and the field.
"""

from __future__ import annotations

import io
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np
import yaml

from tvf.errors import TvfError
from tvf.fusion import (
    HOLE_FILLS,
    PinholeCamera,
    TableLevelError,
    View,
    fill_holes,
    fuse_with_coverage,
    level_on_table,
    pixel_rays,
)
from tvf.geometry import WORKSPACE, Workspace
from tvf.io import atomic_write_bytes

CAMERA_SUFFIXES = (".yaml", ".yml", ".json")
WORKSPACE_STEM = "workspace"
DEFAULT_DEPTH_SCALE = 0.001
"""Metres per unit of a 16-bit depth PNG (ROS REP 118: uint16 depth images are millimetres)."""
MAX_DEPTH = 20.0
"""A depth image whose median reading is beyond this (m) is taken to be in the wrong unit."""
ORTHONORMAL_TOLERANCE = 1e-4
QUATERNION_TOLERANCE = 1e-3

R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""The optical frame (z forward, x right, y down) in the ROS body frame of a camera (x forward, y left,
z up), same origin: its columns are the optical axes written in body coordinates."""

IGNORED_KEYS = frozenset({
    "header", "frame_id", "camera_name", "roi", "binning_x", "binning_y",
    "R", "r", "P", "p", "rectification_matrix", "projection_matrix",
})  # fmt: skip
"""Fields of a ROS CameraInfo message or calibration file that do not concern the fusion."""
CAMERA_KEYS = frozenset({
    "width", "height", "image_width", "image_height", "K", "k", "camera_matrix", "distortion_model",
    "D", "d", "distortion_coefficients", "T_base_camera", "position", "orientation_xyzw",
    "orientation_wxyz", "camera_frame", "depth_scale", "color", "depth",
})  # fmt: skip


@dataclass(frozen=True)
class CameraFile:
    """A parsed camera file: the calibrated camera and where its images are."""

    path: Path
    camera: PinholeCamera
    color: Path
    depth: Path
    depth_scale: float


@dataclass(frozen=True)
class Rgbh:
    """A top-down image: colour uint8 (rows, cols, 3), height float32 metres, where it came from."""

    color: np.ndarray
    height: np.ndarray
    source: Path
    n_views: int = 0
    """0 for a saved RGB-H image."""
    coverage: float = 1.0
    """The fraction of pixels some view measured (the rest is filled by ``hole_fill``)."""
    hole_fill: str | None = None
    """How the holes were filled (:data:`tvf.fusion.HOLE_FILLS`); None for a saved RGB-H image."""
    levelling: tuple[dict, ...] = ()
    """With table levelling, per camera: its name, the tilt (degrees) and the lift (mm) the levelling
    gave its pose (:func:`level_correction`); empty without."""


# --------------------------------------------------------------------------------------------
# Reading the structured files


def _load_mapping(path: Path) -> dict:
    try:
        text = path.read_text()
        value = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (OSError, UnicodeDecodeError) as exc:
        raise TvfError(f"{path}: cannot read the file ({exc.__class__.__name__}); check the path") from None
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        first = " ".join(str(exc).split())[:120]
        raise TvfError(f"{path}: not valid {path.suffix[1:].upper()} ({first})") from None
    if not isinstance(value, dict):
        raise TvfError(
            f"{path}: expected a mapping of fields (docs/real-robot.md), got {type(value).__name__}"
        )
    return value


def _numbers(path: Path, field: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a finite float array of ``shape`` (a flat list of the right length is reshaped)."""
    if isinstance(value, dict) and "data" in value:  # ROS calibration files: {rows, cols, data}
        value = value["data"]
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    size = math.prod(shape)
    if arr is None or arr.size != size or (arr.shape != shape and arr.ndim != 1):
        want = " x ".join(map(str, shape))
        raise TvfError(f"{path}: field {field} must be {want} numbers, got {str(value)[:80]}")
    if not np.isfinite(arr).all():
        raise TvfError(f"{path}: field {field} holds NaN or infinite values")
    return arr.reshape(shape)


def _pick(path: Path, doc: dict, *names: str) -> tuple[str, Any] | None:
    """The one field present among the aliases ``names`` (None if none is)."""
    present = [n for n in names if n in doc]
    if len(present) > 1:
        raise TvfError(f"{path}: fields {' and '.join(present)} say the same thing; keep one")
    return (present[0], doc[present[0]]) if present else None


def _required(path: Path, doc: dict, *names: str) -> tuple[str, Any]:
    found = _pick(path, doc, *names)
    if found is None:
        raise TvfError(
            f"{path}: field {names[0]} is missing (docs/real-robot.md lists the camera file fields)"
        )
    return found


def _positive_int(path: Path, field: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise TvfError(f"{path}: field {field} must be a positive whole number of pixels, got {value!r}")
    return value


def _intrinsics(path: Path, doc: dict) -> tuple[int, int, np.ndarray]:
    width = _positive_int(path, *_required(path, doc, "width", "image_width"))
    height = _positive_int(path, *_required(path, doc, "height", "image_height"))
    field, value = _required(path, doc, "K", "k", "camera_matrix")
    K = _numbers(path, field, value, (3, 3))
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise TvfError(f"{path}: field {field}: the focal lengths fx = K[0], fy = K[4] must be positive")
    if K[0, 1] != 0 or K[1, 0] != 0 or not np.array_equal(K[2], [0, 0, 1]):
        raise TvfError(f"{path}: field {field} must be [fx, 0, cx, 0, fy, cy, 0, 0, 1] (no skew), "
                       f"got {K.ravel().tolist()}")  # fmt: skip
    return width, height, K


def _distortion(path: Path, doc: dict) -> tuple[float, ...]:
    """plumb_bob ``(k1, k2, p1, p2, k3)``; no D, or all zeros under plumb_bob or rational_polynomial, is a
    pinhole. Other models (equidistant, ...) are refused."""
    model = doc.get("distortion_model", "plumb_bob")
    found = _pick(path, doc, "D", "d", "distortion_coefficients")
    values = None if found is None else found[1]
    if isinstance(values, dict) and "data" in values:
        values = values["data"]
    if values is None or values == []:
        return (0.0,) * 5
    field = found[0]
    if model in ("plumb_bob", "rational_polynomial") and isinstance(values, list):
        coeffs = _numbers(path, field, values, (len(values),))
        if not coeffs.any():
            return (0.0,) * 5
    if model != "plumb_bob":
        raise TvfError(
            f"{path}: field distortion_model {model!r} is not supported (only plumb_bob, 5 coefficients); "
            "undistort the images first (e.g. OpenCV's undistort) and write D: [0, 0, 0, 0, 0]"
        )
    return tuple(_numbers(path, field, values, (5,)).tolist())


def _rotation_ok(path: Path, field: str, R: np.ndarray) -> None:
    off = float(np.abs(R.T @ R - np.eye(3)).max())
    if off > ORTHONORMAL_TOLERANCE or np.linalg.det(R) < 0:
        raise TvfError(f"{path}: field {field}: the rotation is not a proper rotation (R^T R - I up to "
                       f"{off:.2g}, det {np.linalg.det(R):+.3f}); write the pose T_base<-camera")  # fmt: skip


def quaternion_matrix(q_xyzw: Sequence[float]) -> np.ndarray:
    """The rotation matrix of a unit quaternion given as (x, y, z, w)."""
    x, y, z, w = q_xyzw
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


def _pose(path: Path, doc: dict) -> np.ndarray:
    """``T_base<-optical`` (4 x 4) from ``T_base_camera`` or ``position`` + ``orientation_xyzw|wxyz``."""
    quat = _pick(path, doc, "orientation_xyzw", "orientation_wxyz")
    if "T_base_camera" in doc and (quat is not None or "position" in doc):
        raise TvfError(f"{path}: give the pose once: T_base_camera, or position + orientation_xyzw")
    if "T_base_camera" in doc:
        T = _numbers(path, "T_base_camera", doc["T_base_camera"], (4, 4))
        if np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-9:
            raise TvfError(
                f"{path}: field T_base_camera: the last row must be [0, 0, 0, 1], got {T[3].tolist()}"
            )
        _rotation_ok(path, "T_base_camera", T[:3, :3])
    else:
        if quat is None or "position" not in doc:
            raise TvfError(f"{path}: field T_base_camera is missing: give a 4 x 4 T_base_camera, or position "
                           "[x, y, z] + orientation_xyzw [x, y, z, w] (or orientation_wxyz)")  # fmt: skip
        q = _numbers(path, quat[0], quat[1], (4,))
        norm = float(np.linalg.norm(q))
        if abs(norm - 1) > QUATERNION_TOLERANCE:
            raise TvfError(f"{path}: field {quat[0]} is not a unit quaternion (norm {norm:.4g})")
        q = q / norm if quat[0] == "orientation_xyzw" else np.roll(q / norm, -1)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = quaternion_matrix(q), _numbers(path, "position", doc["position"], (3,))
    frame = doc.get("camera_frame", "optical")
    if frame not in ("optical", "body"):
        raise TvfError(f"{path}: field camera_frame must be optical (z forward, x right, y down) or body "
                       f"(x forward, y left, z up), got {frame!r}")  # fmt: skip
    if frame == "body":
        T[:3, :3] = T[:3, :3] @ R_BODY_OPTICAL
    return T


def _depth_scale(path: Path, doc: dict) -> float:
    scale = doc.get("depth_scale", DEFAULT_DEPTH_SCALE)
    if isinstance(scale, bool) or not isinstance(scale, int | float) or not 0 < scale < 1:
        raise TvfError(f"{path}: field depth_scale must be metres per unit of the 16-bit depth PNG, "
                       f"between 0 and 1 (0.001 for millimetres), got {scale!r}")  # fmt: skip
    return float(scale)


def _image_path(path: Path, doc: dict, field: str, candidates: tuple[str, ...]) -> Path:
    if field in doc:
        if not isinstance(doc[field], str):
            raise TvfError(f"{path}: field {field} must be a file name, got {doc[field]!r}")
        return path.parent / doc[field]
    for name in candidates:
        if (path.parent / name).exists():
            return path.parent / name
    return path.parent / candidates[0]


def read_camera(path: str | Path) -> CameraFile:
    """Parse a camera file: intrinsics (ROS CameraInfo names), distortion, pose, depth scale, images."""
    path = Path(path)
    doc = _load_mapping(path)
    unknown = sorted(set(doc) - CAMERA_KEYS - IGNORED_KEYS, key=str)
    if unknown:
        raise TvfError(
            f"{path}: unknown field {unknown[0]!r}; the fields are {', '.join(sorted(CAMERA_KEYS))}"
        )
    width, height, K = _intrinsics(path, doc)
    camera = PinholeCamera.from_matrices(
        path.stem, width, height, K, _pose(path, doc), _distortion(path, doc)
    )
    if np.isnan(pixel_rays(camera)).any():
        raise TvfError(f"{path}: field D: the distortion cannot be inverted at some pixels (too strong for "
                       "plumb_bob); undistort the images first and write D: [0, 0, 0, 0, 0]")  # fmt: skip
    stem = path.stem
    color = _image_path(path, doc, "color", (f"{stem}.color.png",))
    depth = _image_path(path, doc, "depth", (f"{stem}.depth.png", f"{stem}.depth.npy"))
    return CameraFile(path, camera, color, depth, _depth_scale(path, doc))


def read_workspace(path: str | Path) -> Workspace:
    """The workspace of a ``workspace.yaml``/``.json``: any of x_min ... z_max, pixel_size (metres, base
    frame); the rest keep today's values."""
    path = Path(path)
    doc = _load_mapping(path)
    fields = WORKSPACE.as_dict()
    for key, value in doc.items():
        if key not in fields:
            raise TvfError(f"{path}: unknown field {key!r}; the fields are {', '.join(fields)}")
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise TvfError(f"{path}: field {key} must be a number of metres, got {value!r}")
    ws = Workspace(**{**fields, **{k: float(v) for k, v in doc.items()}})
    for lo, hi in (("x_min", "x_max"), ("y_min", "y_max"), ("z_min", "z_max")):
        if not getattr(ws, lo) < getattr(ws, hi):
            raise TvfError(f"{path}: field {hi} must be above {lo} ({getattr(ws, hi)} <= {getattr(ws, lo)})")
    if ws.pixel_size <= 0:
        raise TvfError(f"{path}: field pixel_size must be positive, got {ws.pixel_size}")
    for lo, hi in (("x_min", "x_max"), ("y_min", "y_max")):
        n = (getattr(ws, hi) - getattr(ws, lo)) / ws.pixel_size
        if abs(n - round(n)) > 1e-6:
            raise TvfError(f"{path}: field pixel_size {ws.pixel_size} does not divide {lo}..{hi} into whole "
                           f"pixels ({n:.3f})")  # fmt: skip
    return ws


def folder_workspace(folder: str | Path) -> Workspace:
    """The workspace file of a views folder, or :data:`tvf.geometry.WORKSPACE` if it has none."""
    for suffix in CAMERA_SUFFIXES:
        path = Path(folder) / f"{WORKSPACE_STEM}{suffix}"
        if path.exists():
            return read_workspace(path)
    return WORKSPACE


# --------------------------------------------------------------------------------------------
# Reading the images


def _read_image(path: Path, what: str) -> np.ndarray:
    if not path.exists():
        raise TvfError(f"{path}: the {what} image is missing (name it in the camera file, or see "
                       "docs/real-robot.md for the file names)")  # fmt: skip
    try:
        if path.suffix == ".npy":
            return np.load(path, allow_pickle=False)
        return iio.imread(path, plugin="pillow")  # one decoder: a bad file fails once, without fallbacks
    except Exception as exc:  # noqa: BLE001  (any decoder failure is a bad file)
        raise TvfError(
            f"{path}: cannot read the {what} image ({exc.__class__.__name__}); re-record it"
        ) from None


def read_color(path: Path, camera: PinholeCamera) -> np.ndarray:
    """An RGB(A) 8-bit image of the camera's size -> uint8 (H, W, 3)."""
    image = _read_image(path, "colour")
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] not in (3, 4):
        raise TvfError(
            f"{path}: the colour image must be 8-bit RGB, got {image.dtype} of shape {image.shape}"
        )
    if image.shape[:2] != (camera.height, camera.width):
        raise TvfError(f"{path}: the colour image is {image.shape[1]} x {image.shape[0]} but its camera file "
                       f"says width {camera.width}, height {camera.height}")  # fmt: skip
    return np.ascontiguousarray(image[..., :3])


def read_depth(path: Path, camera: PinholeCamera, depth_scale: float) -> np.ndarray:
    """A 16-bit PNG (times ``depth_scale``) or float ``.npy`` (metres) depth image -> float32 metres; NaN
    where there is no reading (0 or NaN in the file)."""
    image = _read_image(path, "depth")
    if path.suffix == ".npy":
        if not np.issubdtype(image.dtype, np.floating):
            raise TvfError(f"{path}: a .npy depth image holds float metres, not {image.dtype}; "
                           "write floats, or a 16-bit PNG with depth_scale")  # fmt: skip
        depth = image.astype(np.float32)
    else:
        if image.dtype != np.uint16:
            raise TvfError(
                f"{path}: a PNG depth image must be 16-bit (uint16 x depth_scale), got {image.dtype}"
            )
        depth = image.astype(np.float32) * np.float32(depth_scale)
    if depth.shape != (camera.height, camera.width):
        raise TvfError(f"{path}: the depth image has shape {depth.shape} but its camera file says width "
                       f"{camera.width}, height {camera.height} (register it to colour)")  # fmt: skip
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)
    if np.isfinite(depth).any() and float(np.nanmedian(depth)) > MAX_DEPTH:
        median = float(np.nanmedian(depth))
        raise TvfError(f"{path}: the median depth is {median:.4g} m; depth must be metres "
                       "(.npy) or units of depth_scale (PNG)")  # fmt: skip
    return depth


@dataclass(frozen=True)
class ViewFiles:
    """One view read from disk: the camera and its colour (uint8) and depth (float32 m, NaN = none)."""

    camera: PinholeCamera
    color: np.ndarray
    depth: np.ndarray
    path: Path


def camera_files(folder: str | Path) -> list[Path]:
    """The camera files of a views folder, by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise TvfError(f"{folder}: no such folder of views (docs/real-robot.md)")
    files = sorted(p for p in folder.iterdir() if p.suffix in CAMERA_SUFFIXES and p.stem != WORKSPACE_STEM
                   and not p.name.startswith("."))  # fmt: skip
    if not files:
        raise TvfError(f"{folder}: holds no camera file (NAME.yaml with NAME.color.png and NAME.depth.png, "
                       "docs/real-robot.md)")  # fmt: skip
    return files


def read_views(folder: str | Path) -> list[ViewFiles]:
    """Every view of a folder: its camera files with their colour and depth images."""
    out = []
    for path in camera_files(folder):
        cam = read_camera(path)
        color, depth = read_color(cam.color, cam.camera), read_depth(cam.depth, cam.camera, cam.depth_scale)
        out.append(ViewFiles(cam.camera, color, depth, path))
    return out


HOLE_FILL_CHOICES = ("auto", *HOLE_FILLS)


def resolve_hole_fill(mode: str, n_views: int) -> str:
    """``auto`` -> the simulator's rule for a rig of ``n_views`` cameras: ``background`` for one camera
    (its occlusion shadows), ``nearest`` for more; any other mode as it is."""
    if mode not in HOLE_FILL_CHOICES:
        raise TvfError(f"unknown hole filling {mode!r}; choose one of {', '.join(HOLE_FILL_CHOICES)}")
    if mode == "auto":
        return "background" if n_views == 1 else "nearest"
    return mode


def level_correction(before: PinholeCamera, after: PinholeCamera) -> dict:
    """How much table levelling moved a camera: its name, the angle (degrees) between the two
    orientations and the lift (mm) of its position."""
    cos = (np.trace(np.asarray(after.rotation) @ np.asarray(before.rotation).T) - 1.0) / 2.0
    return {"camera": before.name, "tilt_deg": round(math.degrees(math.acos(min(1.0, cos))), 4),
            "lift_mm": round(1000.0 * (after.position[2] - before.position[2]), 3)}  # fmt: skip


def level_cameras(views: Sequence[ViewFiles], workspace: Workspace, source: Path) -> list[PinholeCamera]:
    """Each view's camera levelled on the table it sees (:func:`tvf.fusion.level_on_table`)."""
    try:
        return [level_on_table(v.depth, v.camera, workspace) for v in views]
    except TableLevelError as exc:
        raise TvfError(f"{source}: {exc}") from None


def fuse_views(
    views: Sequence[ViewFiles], workspace: Workspace, source: Path, hole_fill: str = "auto",
    level_table: bool = False,
) -> Rgbh:  # fmt: skip
    """The views fused into the top-down image by :mod:`tvf.fusion`, holes filled by ``hole_fill``
    (:func:`resolve_hole_fill`; ``auto`` fills them as the simulator does); with ``level_table``, each
    camera is first levelled on the table it sees (tilt and height of its pose corrected)."""
    fill = resolve_hole_fill(hole_fill, len(views))
    cameras = [v.camera for v in views]
    levelling: tuple[dict, ...] = ()
    if level_table:
        cameras = level_cameras(views, workspace, source)
        levelling = tuple(level_correction(v.camera, c) for v, c in zip(views, cameras, strict=True))
    color, height, covered = fuse_with_coverage([(v.color, v.depth) for v in views], cameras, workspace)
    if not covered.any():
        ws = workspace
        raise TvfError(
            f"{source}: no depth reading of any view falls in the workspace x [{ws.x_min}, {ws.x_max}), "
            f"y [{ws.y_min}, {ws.y_max}), z [{ws.z_min}, {ws.z_max}) m; check T_base_camera (the pose of the "
            "optical frame in the robot base frame), depth_scale and workspace.yaml"
        )
    color, height = fill_holes(color, height, covered, fill)
    return Rgbh(color, height, source, len(views), float(covered.mean()), fill, levelling)


def read_rgbh(path: str | Path, workspace: Workspace = WORKSPACE) -> Rgbh:
    """A saved RGB-H image: an ``.npz`` with ``color`` uint8 (rows, cols, 3) and ``height`` float32 metres."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in ("color", "height") if k in data}
    except (OSError, ValueError) as exc:
        raise TvfError(
            f"{path}: not a readable .npz ({exc.__class__.__name__}); write it with numpy.savez"
        ) from None
    for key in ("color", "height"):
        if key not in arrays:
            raise TvfError(f"{path}: field {key} is missing (an RGB-H .npz holds color and height)")
    color, height = arrays["color"], arrays["height"]
    if color.dtype != np.uint8 or color.shape != (*workspace.shape, 3):
        raise TvfError(f"{path}: field color must be uint8 of shape {(*workspace.shape, 3)}, "
                       f"got {color.dtype} {color.shape}")  # fmt: skip
    if not np.issubdtype(height.dtype, np.floating) or height.shape != workspace.shape:
        raise TvfError(f"{path}: field height must be float metres of shape {workspace.shape}, "
                       f"got {height.dtype} {height.shape}")  # fmt: skip
    if not np.isfinite(height).all():
        raise TvfError(f"{path}: field height holds NaN or infinite values; fill the holes")
    return Rgbh(color, height.astype(np.float32), path)


def load_rgbh(
    path: str | Path, workspace: Workspace, flag: str, hole_fill: str = "auto", level_table: bool = False
) -> Rgbh:  # fmt: skip
    """The top-down image of a views folder (fused, holes filled by ``hole_fill``, cameras levelled on
    the table with ``level_table``) or of a saved ``.npz`` RGB-H image (as it is)."""
    path = Path(path)
    if path.is_dir():
        return fuse_views(read_views(path), workspace, path, hole_fill, level_table)
    if path.suffix == ".npz" and path.is_file():
        return read_rgbh(path, workspace)
    raise TvfError(f"{flag} {path}: give a folder of views or an .npz RGB-H image (docs/real-robot.md)")


# --------------------------------------------------------------------------------------------
# Writing (what `tvf render --export-views` records)


def depth_png_bytes(depth: np.ndarray, depth_scale: float = DEFAULT_DEPTH_SCALE) -> bytes:
    """Depth in metres -> a 16-bit PNG of ``depth / depth_scale`` units, rounded; 0 where there is no
    reading or the depth does not fit 16 bits."""
    units = np.rint(np.asarray(depth, dtype=np.float64) / depth_scale)
    ok = np.isfinite(units) & (units > 0) & (units <= np.iinfo(np.uint16).max)
    return iio.imwrite("<bytes>", np.where(ok, units, 0).astype(np.uint16), extension=".png")


def camera_document(camera: PinholeCamera, depth_scale: float = DEFAULT_DEPTH_SCALE) -> dict:
    """The camera file of ``camera`` as a mapping (the names of :func:`read_camera`)."""
    return {
        "width": camera.width,
        "height": camera.height,
        "K": camera.K.ravel().tolist(),
        "distortion_model": "plumb_bob",
        "D": list(camera.distortion),
        "T_base_camera": camera.T_base_camera.tolist(),
        "camera_frame": "optical",
        "depth_scale": depth_scale,
        "color": f"{camera.name}.color.png",
        "depth": f"{camera.name}.depth.png",
    }


CAMERA_FILE_HEADER = (
    "# tvf camera file (docs/real-robot.md). K (row-major 3 x 3) and D (plumb_bob k1 k2 p1 p2 k3) as in ROS\n"
    "# sensor_msgs/CameraInfo; T_base_camera: the pose of the optical frame (z forward, x right, y down) in\n"
    "# the robot base frame, metres; depth PNG: uint16 x depth_scale metres along the optical axis.\n"
)


WORKSPACE_FILE_HEADER = (
    "# tvf workspace (docs/real-robot.md): bounds in the robot base frame, pixel size; m\n"
)


def write_views(
    folder: str | Path, views: Sequence[View], cameras: Sequence[PinholeCamera],
    workspace: Workspace = WORKSPACE, depth_scale: float = DEFAULT_DEPTH_SCALE,
) -> list[Path]:  # fmt: skip
    """Write what a real rig records: per camera a colour PNG, a 16-bit depth PNG (``depth_scale`` metres a
    unit: millimetres by default) and a camera file, plus ``workspace.yaml``; returns the camera files."""
    folder = Path(folder)
    paths = []
    for (rgb, depth), cam in zip(views, cameras, strict=True):
        doc = camera_document(cam, depth_scale)
        atomic_write_bytes(
            folder / doc["color"], iio.imwrite("<bytes>", np.asarray(rgb, np.uint8), extension=".png")
        )
        atomic_write_bytes(folder / doc["depth"], depth_png_bytes(depth, depth_scale))
        text = CAMERA_FILE_HEADER + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=200)
        paths.append(folder / f"{cam.name}.yaml")
        atomic_write_bytes(paths[-1], text.encode())
    text = WORKSPACE_FILE_HEADER + yaml.safe_dump(workspace.as_dict(), sort_keys=False)
    atomic_write_bytes(folder / f"{WORKSPACE_STEM}.yaml", text.encode())
    return paths


def rgbh_bytes(color: np.ndarray, height: np.ndarray) -> bytes:
    """A saved RGB-H image (``.npz`` with ``color`` and ``height``), as bytes."""
    buf = io.BytesIO()
    np.savez_compressed(buf, color=np.asarray(color, np.uint8), height=np.asarray(height, np.float32))
    return buf.getvalue()
