"""The one fusion (tvf.fusion): calibrated cameras, back-projection, plumb_bob distortion, missing depth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tvf import fusion
from tvf.fusion import PinholeCamera
from tvf.geometry import WORKSPACE

D_REALISTIC = (-0.28, 0.09, 8e-4, -6e-4, -0.012)
"""A plumb_bob calibration of the size a RealSense colour camera or a webcam has."""


def rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp, cy, sy = (f(a) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def oblique_camera(distortion=(0.0,) * 5) -> PinholeCamera:
    """A 64 x 48 camera 0.8 m up, looking down at the workspace at an angle (optical z points down)."""
    R = rotation(math.pi, 0.0, 0.0) @ rotation(-0.5, 0.1, 0.3)
    return PinholeCamera("oblique", 64, 48, 52.0, 51.0, 31.7, 24.2, R, (0.5, -0.2, 0.8), distortion)


def project(camera: PinholeCamera, points: np.ndarray) -> np.ndarray:
    """Base-frame points (N, 3) -> (u, v, depth) with the forward plumb_bob model (the inverse of rays)."""
    R, t = np.asarray(camera.rotation), np.asarray(camera.position)
    pc = (points - t) @ R  # R^T (p - t), row-wise
    x, y = pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2]
    xd, yd = fusion.distort(x, y, camera.distortion)
    return np.stack([camera.fx * xd + camera.cx, camera.fy * yd + camera.cy, pc[:, 2]], axis=-1)


def test_a_camera_holds_K_and_the_pose_as_given():
    cam = oblique_camera()
    K, T = cam.K, cam.T_base_camera
    again = PinholeCamera.from_matrices("again", cam.width, cam.height, K, T, cam.distortion)
    assert again.K.tolist() == K.tolist() and again.T_base_camera.tolist() == T.tolist()
    assert K[0, 2] == 31.7 and K[1, 1] == 51.0 and T[2, 3] == 0.8
    assert hash(again) == hash(PinholeCamera.from_matrices("again", 64, 48, K, T))


@pytest.mark.parametrize("distortion", [(0.0,) * 5, D_REALISTIC])
def test_every_pixel_back_projects_to_a_point_that_projects_onto_it(distortion):
    cam = oblique_camera(distortion)
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 1.2, (cam.height, cam.width))
    points = fusion.depth_to_points(depth, cam)
    uvd = project(cam, points)
    vv, uu = np.mgrid[: cam.height, : cam.width]
    np.testing.assert_allclose(uvd[:, 0], uu.ravel(), atol=1e-7)
    np.testing.assert_allclose(uvd[:, 1], vv.ravel(), atol=1e-7)
    np.testing.assert_allclose(uvd[:, 2], depth.ravel(), atol=1e-9)  # depth is along the optical axis


def test_distort_is_the_plumb_bob_formula():
    x, y = np.array([0.1]), np.array([0.2])
    assert np.allclose(fusion.distort(x, y, (0.1, 0, 0, 0, 0)), ([0.1005], [0.201]))  # r^2 = 0.05
    assert np.allclose(
        fusion.distort(x, y, (0, 0, 0.01, 0, 0)), ([0.1004], [0.2013])
    )  # 2 p1 x y; p1 (r2 + 2y^2)
    assert np.allclose(fusion.distort(x, y, (0, 0, 0, 0.01, 0)), ([0.1007], [0.2004]))


def test_undistort_inverts_distort_and_reports_what_it_cannot():
    xx, yy = np.meshgrid(np.linspace(-0.6, 0.6, 41), np.linspace(-0.45, 0.45, 31))
    x, y = fusion.undistort(*fusion.distort(xx, yy, D_REALISTIC), D_REALISTIC)
    assert np.abs(x - xx).max() < 1e-9 and np.abs(y - yy).max() < 1e-9
    x, _ = fusion.undistort(np.array([0.0, 2.0]), np.array([0.0, 2.0]), (-5.0, 0, 0, 0, 0))
    assert x[0] == 0.0 and np.isnan(x[1])
    with pytest.raises(ValueError, match="5 coefficients"):
        fusion.undistort(xx, yy, (0.1, 0.0))


def test_missing_depth_readings_are_holes_not_points():
    cam = PinholeCamera(
        "down", 200, 200, 200 / 0.6, 200 / 0.6, 99.5, 99.5, rotation(math.pi, 0, 0), (0.5, 0.0, 1.0)
    )
    color = np.full((200, 200, 3), 90, np.uint8)
    depth = np.full((200, 200), 0.97)  # a surface 3 cm above the table
    depth[:, :100] = [0.0, np.nan, np.inf, -1.0] * 25  # no reading in the left half of the image
    points = fusion.depth_to_points(depth, cam)
    assert (
        np.isnan(points.reshape(200, 200, 3)[:, :100]).all()
        and np.isfinite(points.reshape(200, 200, 3)[:, 100:]).all()
    )
    color_out, height, covered = fusion.fuse_with_coverage([(color, depth)], [cam])
    assert 0.3 < covered.mean() < 0.7  # one half of the workspace is seen
    assert np.allclose(height[covered], 0.03, atol=1e-6) and (height[~covered] == 0).all()
    assert (color_out[covered] == 90).all()
    filled_color, filled = fusion.fill_holes(color_out, height, covered)
    assert np.allclose(filled, 0.03, atol=1e-6) and filled.shape == WORKSPACE.shape


def shadow_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 4 cm block (red) on the table (grey) with its occlusion shadow (3 px behind it) and a dropped
    pixel on its top left unmeasured; colour, height, covered on a 20 x 20 grid."""
    height = np.zeros((20, 20), np.float32)
    color = np.full((20, 20, 3), 120, np.uint8)
    height[5:12, 5:12], color[5:12, 5:12] = 0.04, (200, 30, 30)
    covered = np.ones((20, 20), bool)
    covered[5:12, 12:15] = False  # the shadow: between the block's side and the table behind it
    covered[8, 8] = False  # a dropped pixel on the top
    return color, height, covered


def test_background_filling_gives_a_shadow_the_surface_behind_it_and_a_dropout_its_surroundings():
    color, height, covered = shadow_scene()
    truth_h, truth_c = height.copy(), color.copy()
    truth_h[5:12, 12:15], truth_c[5:12, 12:15] = 0.0, 120  # what the shadow hides: the table
    hidden_h, hidden_c = height.copy(), color.copy()
    hidden_h[~covered], hidden_c[~covered] = 0.5, 7  # values under the holes must not leak
    filled_c, filled_h = fusion.fill_holes(hidden_c, hidden_h, covered, "background")
    assert np.array_equal(filled_h, truth_h) and np.array_equal(filled_c, truth_c)
    near_c, near_h = fusion.fill_holes(hidden_c, hidden_h, covered, "nearest")
    assert (near_h[5:12, 12] == 0.04).all() and (near_c[5:12, 12] == (200, 30, 30)).all()  # block smeared
    assert near_h[8, 8] == 0.04 and fusion.fill_holes(hidden_c, hidden_h, covered)[1][5, 12] == 0.04


def test_background_filling_takes_the_lowest_rim_surface_and_stays_near_it():
    height = np.zeros((12, 30), np.float32)
    color = np.zeros((12, 30, 3), np.uint8)
    height[:, :10], height[:, 10:20], height[:, 20:] = 0.08, 0.04, 0.0  # tower | block | table
    color[:, 10:20] = 50
    covered = np.ones((12, 30), bool)
    covered[3:8, 10:14] = False  # hidden behind the tower, on the lower block
    covered[2:4, 25:27] = False  # a 2 x 2 dropout on the table: filled from the table
    _, filled = fusion.fill_holes(color, height, covered, "background")
    assert np.allclose(filled[3:8, 10:14], 0.04) and np.allclose(filled[2:4, 25:27], 0.0)
    tolerance = fusion.BACKGROUND_TOLERANCE
    tilted = height + np.linspace(0, tolerance / 2, 30, dtype=np.float32)  # a rim within the tolerance
    _, filled = fusion.fill_holes(color, tilted, covered, "background")
    assert np.allclose(filled[4:7, 13], tilted[4:7, 14])  # the nearest low rim pixel, not the lowest one


def test_unknown_hole_fillings_and_full_coverage():
    color, height, covered = shadow_scene()
    with pytest.raises(ValueError, match="unknown hole filling 'blur'; choose one of nearest, background"):
        fusion.fill_holes(color, height, covered, "blur")
    everywhere, nowhere = np.ones_like(covered), np.zeros_like(covered)
    for fill in fusion.HOLE_FILLS.values():  # nothing to fill, or nothing to fill from: unchanged
        assert fill(color, height, everywhere)[1] is height and fill(color, height, nowhere)[1] is height
