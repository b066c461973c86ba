"""Sensor realism: a stereo / structured-light depth camera model, camera rigs and calibration errors.

The simulator renders perfect depth. A :class:`SensorConfig` says how a real rig would spoil it, per
rendered view and before the fusion (:mod:`tvf.fusion`), as on a real robot:

* **depth noise**: Gaussian, with a standard deviation that grows with the square of the depth, as a
  stereo camera's does (``sigma(z) = sigma_floor + sigma_1m * (z / 1 m)^2``; z along the optical axis);
* **dropout**: pixels with no reading (depth 0): at depth jumps (object silhouettes, where stereo
  matching fails) with probability ``edge_dropout``, and anywhere with probability ``dropout``;
* **quantisation** of the depth to ``depth_unit`` (the RealSense default unit is 1 mm);
* **colour noise**: Gaussian, ``color_sigma`` grey levels, rounded and clipped to uint8;
* **the rig** (``cameras``): the three Ravens cameras or one in front (:data:`tvf.sim.camera.ONE_CAMERA`),
  and the rig of the goal image (``goal_cameras``; e.g. ``two``: that camera in front and behind);
* **calibration errors**: the fusion back-projects with a perturbed pose of each camera (translation of
  ``calib_translation`` metres in a random direction, rotation of ``calib_rotation_deg`` about a random
  axis through the camera's centre) while the world renders from the true one. ``calib_draw = "episode"``
  draws a new error per episode; ``"fixed"`` draws it once, the same for every episode (one rig's error);
* **table levelling** (``level_table``): before each fusion, every camera's believed pose is corrected so
  the table it sees is level at the table height (:func:`tvf.fusion.level_on_table`), which undoes the
  tilt and height of a calibration error but not its turn about the vertical or its shift along the table;
* **the hole filling** of the fusion (``hole_fill``): ``nearest`` for three cameras, ``background`` for
  one, whose occlusion shadows hide the surface behind each block (:func:`tvf.fusion.fill_background`).

Every draw comes from a ``numpy`` Generator seeded by ``SeedSequence([episode seed, stream, step,
camera])`` (:func:`view_rng`; stream 0 the observations, 1 the goal, 2 the calibration), never from a
global RNG: an episode is reproducible, and independent of the worker that runs it. The preset
``ideal`` (the default) changes nothing: the observations are bit-identical to the simulator's own.

The D415 coefficients: Intel's "Tuning depth cameras for best performance" (Grunnet-Jepsen, Sweetser,
Woodfill) gives the depth RMS error of the D400 cameras as ``z^2 * subpixel / (f * B)``, with a
subpixel disparity error of about 0.08 px on well-textured surfaces, f the focal length in pixels and B
the baseline. For the D415 at 1280 x 720 (HFOV about 65 degrees: f = 640 / tan(32.5 deg) ~ 1000 px,
B = 55 mm) that is 1.45 mm at 1 m; the D435 at 848 x 480 (HFOV 87 degrees: f ~ 450 px, B = 50 mm),
3.6 mm at 1 m. Real scenes are often worse than the textured-wall figure; the presets are a
well-tuned camera, not a worst case. Dropout rates are chosen, not measured (docs/real-robot.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import Literal

import numpy as np
from scipy import ndimage

from tvf.errors import TvfError
from tvf.fusion import HOLE_FILLS, PinholeCamera, View, level_on_table
from tvf.geometry import WORKSPACE, Workspace, rotation_matrix
from tvf.sim.camera import RIGS, Rig

OBSERVATION, GOAL, CALIBRATION = 0, 1, 2
"""The streams of :func:`view_rng`: the scene's observations, the goal image and the calibration error."""
FIXED_CALIBRATION_SEED = 0
"""The seed of the calibration error with ``calib_draw = "fixed"`` (one error for every episode)."""


class SensorError(TvfError):
    """A sensor configuration with a bad value or an unknown preset name."""


@dataclass(frozen=True)
class SensorConfig:
    """How the cameras of a rig differ from perfect ones (module docstring); the default is ideal."""

    name: str = "ideal"
    """A label (the preset's name), recorded with evaluations."""
    cameras: Rig = "three"
    """``three``: the Ravens front, left and right cameras; ``one``: one camera in front, looking down at 60
    degrees (:data:`tvf.sim.camera.ONE_CAMERA`)."""
    sigma_1m: float = 0.0
    """Depth noise (m) at 1 m; it grows with the square of the depth."""
    sigma_floor: float = 0.0
    """Depth noise (m) added at every depth."""
    edge_jump: float = 0.01
    """A pixel is on a silhouette when its depth differs by more than this (m) from a 4-neighbour's."""
    edge_width: int = 1
    """Silhouettes are widened to this many pixels (1: the pixels on both sides of the jump)."""
    edge_dropout: float = 0.0
    """Probability that a silhouette pixel has no reading."""
    dropout: float = 0.0
    """Probability that any pixel has no reading."""
    depth_unit: float = 0.0
    """Depth is rounded to a multiple of this (m); 0: not rounded."""
    color_sigma: float = 0.0
    """Colour noise, in grey levels of 0-255."""
    calib_translation: float = 0.0
    """Length (m) of each camera's position error, in a random direction."""
    calib_rotation_deg: float = 0.0
    """Angle (degrees) of each camera's orientation error, about a random axis."""
    calib_draw: Literal["episode", "fixed"] = "episode"
    """``episode``: a new calibration error per episode seed; ``fixed``: the same error in every episode."""
    level_table: bool = False
    """Level each camera on the table it sees before the fusion (:func:`tvf.fusion.level_on_table`): a
    plane fit that corrects a pose's tilt and height, as a real rig can check its calibration each frame."""
    goal_cameras: Rig | None = None
    """The rig the goal image is recorded with (None: ``cameras``): ``two`` records it with the one camera
    from in front and from behind (:data:`tvf.sim.camera.ONE_CAMERA_BACK`), so the parts of a finished
    structure that its taller parts hide from one side are seen from the other (the scene: ``cameras``)."""
    hole_fill: Literal["nearest", "background"] = "nearest"
    """How the fusion fills what no camera measured (:data:`tvf.fusion.HOLE_FILLS`): ``nearest`` (the
    three-camera rig, as the stored datasets were made) or ``background`` (one camera: the lowest surface
    on a hole's rim, what an occlusion shadow hides)."""

    def __post_init__(self) -> None:
        if self.cameras not in RIGS:
            raise SensorError(f"sensor {self.name!r}: cameras must be one of {', '.join(RIGS)}, "
                              f"not {self.cameras!r}")  # fmt: skip
        if self.goal_cameras is not None and self.goal_cameras not in RIGS:
            raise SensorError(f"sensor {self.name!r}: goal_cameras must be one of {', '.join(RIGS)} or None, "
                              f"not {self.goal_cameras!r}")  # fmt: skip
        for key in ("sigma_1m", "sigma_floor", "edge_jump", "depth_unit", "color_sigma",
                    "calib_translation", "calib_rotation_deg"):  # fmt: skip
            value = getattr(self, key)
            if not (math.isfinite(value) and value >= 0):
                raise SensorError(f"sensor {self.name!r}: {key} must be a finite number >= 0, not {value!r}")
        for key in ("edge_dropout", "dropout"):
            value = getattr(self, key)
            if not 0.0 <= value <= 1.0:
                raise SensorError(f"sensor {self.name!r}: {key} is a probability in [0, 1], not {value!r}")
        if not (isinstance(self.edge_width, int) and self.edge_width >= 1):
            raise SensorError(
                f"sensor {self.name!r}: edge_width must be an integer >= 1, not {self.edge_width!r}"
            )
        if not isinstance(self.level_table, bool):
            raise SensorError(
                f"sensor {self.name!r}: level_table must be true or false, not {self.level_table!r}"
            )
        if self.calib_draw not in ("episode", "fixed"):
            raise SensorError(f"sensor {self.name!r}: calib_draw must be 'episode' or 'fixed', "
                              f"not {self.calib_draw!r}")  # fmt: skip
        if self.hole_fill not in HOLE_FILLS:
            raise SensorError(f"sensor {self.name!r}: hole_fill must be one of {', '.join(HOLE_FILLS)}, "
                              f"not {self.hole_fill!r}")  # fmt: skip

    @property
    def corrupts_views(self) -> bool:
        """Whether any image is changed (noise, dropout, quantisation or colour noise)."""
        return any((self.sigma_1m, self.sigma_floor, self.edge_dropout, self.dropout, self.depth_unit,
                    self.color_sigma))  # fmt: skip

    @property
    def miscalibrated(self) -> bool:
        return bool(self.calib_translation or self.calib_rotation_deg)

    @property
    def ideal(self) -> bool:
        """Perfect cameras (the rig may still be ``one``)."""
        return not (self.corrupts_views or self.miscalibrated or self.level_table)

    @property
    def goal_rig(self) -> Rig:
        """The rig the goal image is recorded with: ``goal_cameras``, else ``cameras``."""
        return self.goal_cameras or self.cameras

    def sigma(self, depth: np.ndarray) -> np.ndarray:
        """The depth noise's standard deviation (m) at ``depth`` (m along the optical axis)."""
        return self.sigma_floor + self.sigma_1m * np.square(depth)

    def apply(
        self, views: Sequence[View], cameras: Sequence[PinholeCamera], seed: int, step: int, stream: int,
        workspace: Workspace = WORKSPACE,
    ) -> tuple[list[View], tuple[PinholeCamera, ...]]:  # fmt: skip
        """The views as this sensor records them and the cameras as the rig believes them to be.

        ``seed`` is the episode's, ``step`` the number of actions so far, ``stream`` :data:`OBSERVATION`
        or :data:`GOAL`; ``workspace`` is where ``level_table`` looks for the table. An ideal sensor
        returns its inputs unchanged.
        """
        views, cameras = list(views), tuple(cameras)
        if self.corrupts_views:
            views = [corrupt_view(rgb, depth, self, view_rng(seed, stream, step, i))
                     for i, (rgb, depth) in enumerate(views)]  # fmt: skip
        if self.miscalibrated:
            cameras = calibrated_cameras(cameras, self, seed)
        if self.level_table:
            cameras = tuple(
                level_on_table(depth, cam, workspace) for (_, depth), cam in zip(views, cameras, strict=True)
            )
        return views, cameras


def view_rng(seed: int, stream: int, step: int, camera: int) -> np.random.Generator:
    """The generator of one camera's draws: ``SeedSequence([seed, stream, step, camera])``."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(stream), int(step), int(camera)]))


# --------------------------------------------------------------------------------------------
# Depth and colour


def silhouettes(depth: np.ndarray, jump: float, width: int = 1) -> np.ndarray:
    """Pixels whose depth differs by more than ``jump`` from a 4-neighbour's (no reading counts as far),
    widened to ``width`` pixels."""
    d = np.where(np.isfinite(depth) & (depth > 0), depth, np.inf).astype(np.float64)
    edge = np.zeros(d.shape, bool)
    with np.errstate(invalid="ignore"):  # inf - inf: two pixels without a reading are no edge
        dv, du = np.abs(np.diff(d, axis=0)) > jump, np.abs(np.diff(d, axis=1)) > jump
    edge[1:] |= dv
    edge[:-1] |= dv
    edge[:, 1:] |= du
    edge[:, :-1] |= du
    if width > 1:
        edge = ndimage.binary_dilation(edge, iterations=width - 1)
    return edge


def corrupt_view(
    rgb: np.ndarray, depth: np.ndarray, cfg: SensorConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """One camera's colour (uint8) and depth (float32 m, 0 = no reading) as ``cfg``'s camera records them.

    Draws, in this order: depth noise, dropout, silhouette dropout, colour noise (each only when used).
    """
    d = np.asarray(depth, dtype=np.float64)
    valid = np.isfinite(d) & (d > 0)
    edge = silhouettes(d, cfg.edge_jump, cfg.edge_width) if cfg.edge_dropout else None
    if cfg.sigma_1m or cfg.sigma_floor:
        d = d + rng.standard_normal(d.shape) * cfg.sigma(np.where(valid, d, 0.0))
    drop = ~valid
    if cfg.dropout:
        drop |= rng.random(d.shape) < cfg.dropout
    if edge is not None:
        drop |= edge & (rng.random(d.shape) < cfg.edge_dropout)
    if cfg.depth_unit:
        d = np.round(d / cfg.depth_unit) * cfg.depth_unit
    out_depth = np.where(drop | ~(d > 0), 0.0, d).astype(np.float32)
    out_rgb = np.asarray(rgb)
    if cfg.color_sigma:
        noisy = out_rgb.astype(np.float64) + rng.normal(0.0, cfg.color_sigma, out_rgb.shape)
        out_rgb = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    return out_rgb, out_depth


# --------------------------------------------------------------------------------------------
# Calibration


def perturb_camera(
    camera: PinholeCamera, translation: Sequence[float], rotvec: Sequence[float]
) -> PinholeCamera:
    """``camera`` moved by ``translation`` (m, base frame) and turned by ``rotvec`` (radians, base frame)
    about its optical centre: the pose a slightly wrong calibration reports."""
    R = rotation_matrix(rotvec) @ np.asarray(camera.rotation)
    return replace(camera, rotation=R, position=np.asarray(camera.position) + np.asarray(translation, float))


def calibration_error(cfg: SensorConfig, seed: int, camera: int) -> tuple[np.ndarray, np.ndarray]:
    """One camera's (translation, rotation vector): the configured lengths in directions drawn uniformly
    on the sphere from :func:`view_rng` (stream :data:`CALIBRATION`)."""
    draw_seed = FIXED_CALIBRATION_SEED if cfg.calib_draw == "fixed" else seed
    rng = view_rng(draw_seed, CALIBRATION, 0, camera)
    directions = rng.standard_normal((2, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return cfg.calib_translation * directions[0], math.radians(cfg.calib_rotation_deg) * directions[1]


def calibrated_cameras(
    cameras: Sequence[PinholeCamera], cfg: SensorConfig, seed: int
) -> tuple[PinholeCamera, ...]:
    """The cameras as a rig with ``cfg``'s calibration errors believes them to be, for episode ``seed``."""
    return tuple(perturb_camera(cam, *calibration_error(cfg, seed, i)) for i, cam in enumerate(cameras))


# --------------------------------------------------------------------------------------------
# Presets

_D415 = dict(sigma_1m=0.00145, edge_dropout=0.5, dropout=0.002, depth_unit=0.001, color_sigma=2.0)
_CALIB = dict(calib_translation=0.003, calib_rotation_deg=1.0)
_ONE = dict(cameras="one", hole_fill="background")

SENSORS: dict[str, SensorConfig] = {
    s.name: s
    for s in (
        SensorConfig("ideal"),
        SensorConfig("one", **_ONE),
        SensorConfig("d415", **_D415),
        SensorConfig("d415-one", **_ONE, **_D415),
        SensorConfig("d415-one-calib", **_ONE, **_D415, **_CALIB),
        SensorConfig("d415-one-calib-level", **_ONE, **_D415, **_CALIB, level_table=True),
        SensorConfig("d415-one-goal2", **_ONE, **_D415, goal_cameras="two"),
        SensorConfig("d435-one", **_ONE, **{**_D415, "sigma_1m": 0.0036}),
    )
}
"""The named sensors: ``ideal`` (perfect, the default), ``one`` (one perfect camera), ``d415`` (three
D415-like cameras), ``d415-one`` (one), ``d415-one-calib`` (one, miscalibrated by 3 mm and 1 degree, drawn
per episode), ``d415-one-calib-level`` (that camera levelled on the table before each fusion),
``d415-one-goal2`` (``d415-one`` with the goal recorded from in front and from behind) and ``d435-one``
(one camera with the D435's larger noise)."""

FIELDS = tuple(f.name for f in fields(SensorConfig))


def get_sensor(sensor: str | SensorConfig) -> SensorConfig:
    """A preset by name (:data:`SENSORS`), or a config as it is."""
    if isinstance(sensor, SensorConfig):
        return sensor
    if sensor not in SENSORS:
        raise SensorError(f"unknown sensor {sensor!r}; choose one of {', '.join(SENSORS)}")
    return SENSORS[sensor]
