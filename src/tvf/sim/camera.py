"""Observation pipeline: simulated RGB-D cameras fused into a top-down colour + height map.

Three oblique RGB-D cameras (the Ravens RealSense D415 poses) are rendered with PyBullet's
TinyRenderer and fused by :mod:`tvf.fusion` (the one fusion, which camera files use too): back-projected
to world points and binned into the 160 x 160 workspace grid of :mod:`tvf.geometry` (floor rule,
half-open bounds). Per pixel the height is the highest point any camera saw; the colour is the mean over
the cameras whose own top point reaches that height. Each camera is handed to the fusion as a
:class:`tvf.fusion.PinholeCamera` whose cx, cy carry the renderer's sampling offset.
:func:`orthographic_heightmap` renders an exact top-down reference from a camera 1000 m up.

Measured facts this module relies on (checked by ``tests/sim/test_camera.py``):

* **TinyRenderer samples pixel (row v, col u) at image point (u, v + 1)**, not at the pixel centre
  (u + 0.5, v + 0.5): it rasterises at integer GL coordinates with the y axis flipped. Back-projection
  uses that offset (:data:`TINY_RENDERER_SAMPLE_OFFSET`); the Ravens formula ``(u - cx, v - cy)``
  puts every point one pixel off along the image rows (height MAE 1.7 mm instead of 0.05 mm at
  640 x 480).
* Table points at z = 0 come back a few micrometres either side of 0, so points down to
  ``z_min - z_tolerance`` are kept (heights clipped at 0); a strict half-open lower bound would
  punch holes into the table.

Default (``ObservationConfig``): cameras at 480 x 360, hole filling on. Against the orthographic
cell-max reference on 6 cluttered scenes it gives height MAE 0.11 mm (640 x 480: 0.11 mm), 0.23 %
of pixels more than 5 mm off, 0.7 % raw holes, for ~0.08 s per observation on one idle core
(640 x 480: ~0.15 s). Full table and reasoning: ``docs/observation.md``; numbers:
``benchmarks/camera.py``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Literal

import numpy as np
import pybullet as p

from tvf import fusion
from tvf.fusion import (  # noqa: F401  (bin_points, fill_holes and the tolerances are re-exported)
    COLOR_HEIGHT_TOLERANCE,
    Z_TOLERANCE,
    PinholeCamera,
    View,
    bin_points,
    fill_holes,
)
from tvf.geometry import WORKSPACE, Workspace

#: Only TinyRenderer: in DIRECT mode PyBullet silently renders ER_BULLET_HARDWARE_OPENGL requests with
#: TinyRenderer too (identical images, measured); a GL/EGL renderer would need its own sample offset.
Renderer = Literal["tiny"]

#: Image point (u, v) that TinyRenderer samples for pixel (v, u) is (u + du, v + dv); measured.
TINY_RENDERER_SAMPLE_OFFSET: tuple[float, float] = (0.0, 1.0)

_RENDERERS = {"tiny": p.ER_TINY_RENDERER}
_SAMPLE_OFFSETS = {"tiny": TINY_RENDERER_SAMPLE_OFFSET}


def sample_offset(renderer: Renderer) -> tuple[float, float]:
    """Sub-pixel (du, dv) at which ``renderer`` samples pixel (v, u)."""
    return _SAMPLE_OFFSETS[renderer]


# --------------------------------------------------------------------------------------------
# Cameras


@dataclass(frozen=True)
class CameraConfig:
    """A pinhole camera: pose (PyBullet Euler XYZ), image size, focal length in pixels, z range."""

    name: str
    position: tuple[float, float, float]
    euler_xyz: tuple[float, float, float]
    width: int
    height: int
    focal: float
    z_near: float = 0.01
    z_far: float = 10.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", tuple(float(v) for v in self.position))
        object.__setattr__(self, "euler_xyz", tuple(float(v) for v in self.euler_xyz))

    @property
    def rotation(self) -> np.ndarray:
        """Camera-to-world rotation (3, 3); camera axes are x right, y down, z forward."""
        quat = p.getQuaternionFromEuler(self.euler_xyz)
        return np.array(p.getMatrixFromQuaternion(quat), dtype=np.float64).reshape(3, 3)

    @property
    def fov_y_deg(self) -> float:
        """Vertical field of view in degrees."""
        return math.degrees(2.0 * math.atan(0.5 * self.height / self.focal))

    @property
    def fov_x_deg(self) -> float:
        """Horizontal field of view in degrees."""
        return math.degrees(2.0 * math.atan(0.5 * self.width / self.focal))

    def view_matrix(self) -> tuple[float, ...]:
        rot = self.rotation
        eye = np.asarray(self.position)
        look, up = rot @ (0.0, 0.0, 1.0), rot @ (0.0, -1.0, 0.0)
        return p.computeViewMatrix(eye.tolist(), (eye + look).tolist(), up.tolist())

    def projection_matrix(self) -> tuple[float, ...]:
        return p.computeProjectionMatrixFOV(self.fov_y_deg, self.width / self.height, self.z_near, self.z_far)

    def pinhole(self, offset: tuple[float, float]) -> PinholeCamera:
        """This camera as calibrated intrinsics + pose for a renderer that samples pixel (v, u) at image
        point (u + du, v + dv): ``cx = W/2 - du``, ``cy = H/2 - dv`` (OpenCV's rule, docs/real-robot.md)."""
        du, dv = offset
        cx, cy = 0.5 * self.width - du, 0.5 * self.height - dv
        return PinholeCamera(self.name, self.width, self.height, self.focal, self.focal, cx, cy,
                             self.rotation, self.position)  # fmt: skip

    def rescaled(self, width: int, height: int) -> CameraConfig:
        """Same pose and horizontal field of view at another resolution (focal scales with width)."""
        return replace(self, width=int(width), height=int(height), focal=self.focal * width / self.width)


REFERENCE_CAMERAS: tuple[CameraConfig, ...] = (
    CameraConfig("front", (1.0, 0.0, 0.75), (math.pi / 4, math.pi, -math.pi / 2), 640, 480, 450.0),
    CameraConfig("left", (0.0, 0.5, 0.75), (math.pi / 4.5, math.pi, math.pi / 4), 640, 480, 450.0),
    CameraConfig("right", (0.0, -0.5, 0.75), (math.pi / 4.5, math.pi, 3 * math.pi / 4), 640, 480, 450.0),
)


def reference_cameras(width: int = 640, height: int = 480) -> tuple[CameraConfig, ...]:
    """The three Ravens RealSense cameras (front, left, right) rescaled to ``width`` x ``height``."""
    return tuple(cam.rescaled(width, height) for cam in REFERENCE_CAMERAS)


ONE_CAMERA_ELEVATION_DEG = 60.0
ONE_CAMERA_DISTANCE = 0.8


def _facing_workspace_centre(name: str, side: int) -> CameraConfig:
    """A camera :data:`ONE_CAMERA_DISTANCE` from the workspace centre (0.5, 0, 0) on the +x (``side`` 1,
    opposite the arm) or -x (``side`` -1, behind it) side, looking at it :data:`ONE_CAMERA_ELEVATION_DEG`
    below the horizontal, with the intrinsics of the reference cameras."""
    elevation = math.radians(ONE_CAMERA_ELEVATION_DEG)
    position = (0.5 + side * ONE_CAMERA_DISTANCE * math.cos(elevation), 0.0,
                ONE_CAMERA_DISTANCE * math.sin(elevation))  # fmt: skip
    tilt = math.radians(90.0 - ONE_CAMERA_ELEVATION_DEG)
    return CameraConfig(name, position, (tilt, math.pi, -side * math.pi / 2), 640, 480, 450.0)


#: The single camera of a rig like the paper's real set-up: in front of the workspace (opposite the arm),
#: looking down at 60 degrees below the horizontal at the workspace centre from 0.8 m, with the same
#: intrinsics as the reference cameras. At 480 x 360 the whole 0.5 x 0.5 m workspace, up to z = 0.28 m,
#: is in view (image rows 3-287, columns 45-435) at 0.43-0.92 m depth (docs/real-robot.md).
ONE_CAMERA = _facing_workspace_centre("one", 1)

#: :data:`ONE_CAMERA` moved to the opposite side of the workspace (behind the arm, which is lifted out of
#: every render), looking back at the centre at the same angle and distance: what the one camera sees from
#: its second pose when the goal is recorded from two sides (rig ``two``).
ONE_CAMERA_BACK = _facing_workspace_centre("one-back", -1)

Rig = Literal["three", "one", "two"]
RIGS: dict[str, tuple[CameraConfig, ...]] = {
    "three": REFERENCE_CAMERAS,
    "one": (ONE_CAMERA,),
    "two": (ONE_CAMERA, ONE_CAMERA_BACK),
}
"""The camera rigs: the three Ravens cameras (the default), the one camera of a real set-up, or that
camera's two poses, in front and behind (a goal recorded from both sides: ``SensorConfig.goal_cameras``)."""


@dataclass(frozen=True)
class ObservationConfig:
    """How an observation is rendered. Defaults: see ``docs/observation.md`` (measured)."""

    width: int = 480
    height: int = 360
    shadows: bool = False
    renderer: Renderer = "tiny"
    fill_holes: bool = True
    rig: Rig = "three"
    """Which cameras render: ``three`` (the Ravens front, left, right) or ``one`` (:data:`ONE_CAMERA`);
    a :class:`tvf.sim.sensors.SensorConfig` chooses it for an environment."""

    def __post_init__(self) -> None:
        if self.renderer not in _RENDERERS:
            raise ValueError(f"renderer must be one of {sorted(_RENDERERS)}, got {self.renderer!r}")
        if self.rig not in RIGS:
            raise ValueError(f"rig must be one of {sorted(RIGS)}, got {self.rig!r}")

    def cameras(self) -> tuple[CameraConfig, ...]:
        return tuple(cam.rescaled(self.width, self.height) for cam in RIGS[self.rig])

    def pinholes(self) -> tuple[PinholeCamera, ...]:
        """The cameras as calibrated intrinsics + poses, the renderer's sampling offset in cx, cy."""
        return tuple(cam.pinhole(sample_offset(self.renderer)) for cam in self.cameras())


# --------------------------------------------------------------------------------------------
# Rendering


def linearize_depth(zbuffer: np.ndarray, z_near: float, z_far: float) -> np.ndarray:
    """OpenGL z-buffer values in [0, 1] -> distance along the optical axis in metres (float64)."""
    zb = np.asarray(zbuffer, dtype=np.float64)
    return 2.0 * z_near * z_far / (z_far + z_near - (2.0 * zb - 1.0) * (z_far - z_near))


def _render(
    client_id: int, camera: CameraConfig, shadows: bool, renderer: Renderer
) -> tuple[np.ndarray, np.ndarray]:
    """Render; returns RGB uint8 (H, W, 3) and float64 depth (H, W) in metres."""
    _, _, rgba, zbuf, _ = p.getCameraImage(
        camera.width,
        camera.height,
        viewMatrix=camera.view_matrix(),
        projectionMatrix=camera.projection_matrix(),
        shadow=int(shadows),
        flags=p.ER_NO_SEGMENTATION_MASK,
        renderer=_RENDERERS[renderer],
        physicsClientId=client_id,
    )
    # Without numpy support pybullet returns flat tuples; asarray + reshape handles both forms.
    if not isinstance(zbuf, np.ndarray):
        _warn_no_numpy()
    rgb = np.asarray(rgba, dtype=np.uint8).reshape(camera.height, camera.width, 4)[..., :3]
    zb = np.asarray(zbuf, dtype=np.float32).reshape(camera.height, camera.width)
    return np.ascontiguousarray(rgb), linearize_depth(zb, camera.z_near, camera.z_far)


@lru_cache(maxsize=1)
def _warn_no_numpy() -> None:
    warnings.warn(
        "pybullet was built without numpy: getCameraImage returns tuples and rendering is much slower",
        RuntimeWarning,
        stacklevel=3,
    )


def render_rgbd(
    client_id: int, camera: CameraConfig, shadows: bool = False, renderer: Renderer = "tiny"
) -> tuple[np.ndarray, np.ndarray]:
    """Render one camera: RGB uint8 (H, W, 3) and depth float32 (H, W) in metres along the axis."""
    rgb, depth = _render(client_id, camera, shadows, renderer)
    return rgb, depth.astype(np.float32)


# --------------------------------------------------------------------------------------------
# Back-projection and fusion: the math is tvf.fusion's (shared with camera files, tvf.views); these
# adapters take the simulator's cameras and the renderer's sample offset.


def depth_to_points(
    depth: np.ndarray, camera: CameraConfig, offset: tuple[float, float] = TINY_RENDERER_SAMPLE_OFFSET
) -> np.ndarray:
    """Depth image (H, W) -> world points (H*W, 3), row-major over pixels."""
    return fusion.depth_to_points(depth, camera.pinhole(offset))


def fuse_with_coverage(
    views: Sequence[View],
    cameras: Sequence[CameraConfig],
    workspace: Workspace = WORKSPACE,
    offset: tuple[float, float] = TINY_RENDERER_SAMPLE_OFFSET,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`tvf.fusion.fuse_with_coverage` of the simulator's cameras: colour, height, covered mask."""
    return fusion.fuse_with_coverage(views, [c.pinhole(offset) for c in cameras], workspace)


def fuse(
    views: Sequence[View],
    cameras: Sequence[CameraConfig],
    workspace: Workspace = WORKSPACE,
    fill: bool = False,
    offset: tuple[float, float] = TINY_RENDERER_SAMPLE_OFFSET,
) -> tuple[np.ndarray, np.ndarray]:
    """Fuse RGB-D ``views`` [(rgb, depth), ...] -> colour uint8 (rows, cols, 3), height float32."""
    return fusion.fuse(views, [c.pinhole(offset) for c in cameras], workspace, fill)


def render_views(client_id: int, config: ObservationConfig | None = None) -> list[View]:
    """Render the observation's cameras: one (colour uint8, depth float32 metres) per camera."""
    cfg = config or ObservationConfig()
    return [render_rgbd(client_id, cam, cfg.shadows, cfg.renderer) for cam in cfg.cameras()]


def observe(
    client_id: int, config: ObservationConfig | None = None, workspace: Workspace = WORKSPACE
) -> tuple[np.ndarray, np.ndarray]:
    """Render the three cameras and fuse them: colour uint8 (160, 160, 3), height float32 (160, 160)."""
    cfg = config or ObservationConfig()
    return fusion.fuse(render_views(client_id, cfg), cfg.pinholes(), workspace, cfg.fill_holes)


# --------------------------------------------------------------------------------------------
# Orthographic reference

ORTHO_DISTANCE = 1000.0


def orthographic_camera(
    workspace: Workspace = WORKSPACE, supersample: int = 1, renderer: Renderer = "tiny"
) -> CameraConfig:
    """A camera 1000 m above the table whose samples sit on the pixel centres of the workspace grid.

    With ``supersample = k`` it has k x k samples per workspace pixel, at the centres of the k x k
    sub-cells. Its image columns run along world y and its rows along world x (Euler (0, pi, -pi/2)).
    The pose is shifted by the renderer's sampling offset so that samples land where intended.
    """
    step = workspace.pixel_size / supersample
    euler = (0.0, math.pi, -math.pi / 2)
    rot = CameraConfig("tmp", (0, 0, 0), euler, 1, 1, 1.0).rotation
    du, dv = sample_offset(renderer)
    cx, cy = workspace.center
    shift = rot @ ((0.5 - du) * step, (0.5 - dv) * step, 0.0)
    eye = np.array([cx, cy, workspace.z_min + ORTHO_DISTANCE]) + shift
    return CameraConfig(
        name="orthographic",
        position=tuple(eye),
        euler_xyz=euler,
        width=workspace.rows * supersample,  # image x (columns) = world y
        height=workspace.cols * supersample,  # image y (rows) = world x
        focal=ORTHO_DISTANCE / step,
        z_near=ORTHO_DISTANCE - (workspace.z_max - workspace.z_min) - 0.02,
        z_far=ORTHO_DISTANCE + 0.05,
    )


def orthographic_heightmap(
    client_id: int,
    workspace: Workspace = WORKSPACE,
    with_color: bool = True,
    supersample: int = 1,
    renderer: Renderer = "tiny",
) -> tuple[np.ndarray | None, np.ndarray]:
    """Exact top-down colour (uint8) and height (float32) maps; ``color`` is None if not requested.

    ``supersample = 1`` samples each pixel's centre. ``supersample = k > 1`` keeps the highest of
    k x k samples per pixel (the colour of that top sample), which is what fusion estimates.
    Pixels that see nothing (no table) are 0.
    """
    cam = orthographic_camera(workspace, supersample, renderer)
    rgb, depth = _render(client_id, cam, shadows=False, renderer=renderer)
    height, color = fusion.bin_points(fusion.depth_to_points(depth, cam.pinhole(sample_offset(renderer))),
                                      rgb, workspace)  # fmt: skip
    out_h = np.nan_to_num(height, nan=0.0).astype(np.float32)
    if not with_color:
        return None, out_h
    return np.clip(np.rint(np.nan_to_num(color, nan=0.0)), 0, 255).astype(np.uint8), out_h


# --------------------------------------------------------------------------------------------
# Measurement scene (used by the tests, the benchmark and the table in docs/observation.md)

TILE_HALF = (0.025, 0.025, 0.0025)
CUBE_HALF = (0.02, 0.02, 0.02)
TABLE_RGBA = (0.47, 0.42, 0.36, 1.0)
_PALETTE = (
    (0.86, 0.25, 0.22, 1.0),
    (0.22, 0.55, 0.86, 1.0),
    (0.30, 0.72, 0.34, 1.0),
    (0.95, 0.78, 0.20, 1.0),
    (0.62, 0.36, 0.75, 1.0),
    (0.95, 0.55, 0.20, 1.0),
)


def add_box(
    client_id: int,
    half_extents: tuple[float, float, float],
    position: tuple[float, float, float],
    yaw: float = 0.0,
    rgba: tuple[float, float, float, float] = (0.8, 0.2, 0.2, 1.0),
) -> int:
    """A static visual+collision box; returns its body id."""
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half_extents, rgbaColor=rgba, physicsClientId=client_id)
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half_extents, physicsClientId=client_id)
    quat = p.getQuaternionFromEuler((0.0, 0.0, yaw))
    return p.createMultiBody(0.0, col, vis, position, quat, physicsClientId=client_id)


def add_table(client_id: int, workspace: Workspace = WORKSPACE) -> int:
    """A 2 x 2 m slab whose top face is the plane z = z_min."""
    cx, cy = workspace.center
    return add_box(client_id, (1.0, 1.0, 0.01), (cx, cy, workspace.z_min - 0.01), 0.0, TABLE_RGBA)


def build_fidelity_scene(
    client_id: int,
    seed: int,
    n_tiles: int = 4,
    n_stacks: int = 4,
    workspace: Workspace = WORKSPACE,
) -> list[int]:
    """Table + 5 x 5 x 0.5 cm tiles + stacks of 1-3 four-centimetre cubes at random, non-overlapping poses.

    Footprints are kept apart (bounding circles) and 4 cm inside the workspace edge; each cube in a
    stack is shifted up to 5 mm and turned up to 15 degrees relative to the one below.
    """
    rng = np.random.default_rng(seed)
    ids = [add_table(client_id, workspace)]
    placed: list[np.ndarray] = []
    radius = math.hypot(0.025, 0.025) + 0.005
    margin = 0.04
    lo = np.array([workspace.x_min + margin, workspace.y_min + margin])
    hi = np.array([workspace.x_max - margin, workspace.y_max - margin])
    kinds = ["tile"] * n_tiles + ["stack"] * n_stacks
    for kind in kinds:
        for _ in range(200):
            xy = rng.uniform(lo, hi)
            if all(np.linalg.norm(xy - q) > 2 * radius for q in placed):
                break
        else:
            raise RuntimeError("could not place all objects; use fewer")
        placed.append(xy)
        yaw = float(rng.uniform(-math.pi, math.pi))
        if kind == "tile":
            rgba = _PALETTE[int(rng.integers(len(_PALETTE)))]
            pos = (float(xy[0]), float(xy[1]), workspace.z_min + TILE_HALF[2])
            ids.append(add_box(client_id, TILE_HALF, pos, yaw, rgba))
            continue
        for level in range(int(rng.integers(1, 4))):
            rgba = _PALETTE[int(rng.integers(len(_PALETTE)))]
            pos = (float(xy[0]), float(xy[1]), workspace.z_min + CUBE_HALF[2] * (2 * level + 1))
            ids.append(add_box(client_id, CUBE_HALF, pos, yaw, rgba))
            xy = xy + rng.uniform(-0.005, 0.005, size=2)
            yaw += float(rng.uniform(-math.pi / 12, math.pi / 12))
    return ids
