"""Camera files (tvf.views): the formats a real rig records, their frames, one-line errors for bad files."""

from __future__ import annotations

import json
import math
import re

import imageio.v3 as iio
import numpy as np
import pytest
import yaml

from tvf import fusion, views
from tvf.errors import TvfError
from tvf.fusion import PinholeCamera
from tvf.geometry import WORKSPACE

TOP = 0.03
"""The synthetic scene: a flat surface this high (m) over the whole workspace."""


def look_down(name: str, position, tilt: float, width: int = 640, height: int = 480) -> PinholeCamera:
    """A camera at ``position`` whose optical axis points down, tilted by ``tilt`` about the base x axis."""
    c, s = math.cos(tilt), math.sin(tilt)
    R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ np.diag([1.0, -1.0, -1.0])  # optical z -> base -z
    return PinholeCamera(name, width, height, 450.0, 451.0, width / 2 - 0.3, height / 2 + 0.4, R, position)


def plane_view(cam: PinholeCamera, z: float, rgb) -> tuple[np.ndarray, np.ndarray]:
    """What ``cam`` sees of the plane at height ``z``: depth along the optical axis per pixel."""
    vv, uu = np.mgrid[: cam.height, : cam.width]
    ray = (
        np.stack([(uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, np.ones_like(uu, float)], -1)
        @ np.asarray(cam.rotation).T
    )
    depth = (z - cam.position[2]) / ray[..., 2]
    return np.full((cam.height, cam.width, 3), rgb, np.uint8), depth.astype(np.float32)


CAMERAS = (look_down("a", (0.5, -0.1, 0.9), 0.25), look_down("b", (0.5, 0.1, 0.9), -0.25))


@pytest.fixture
def rig(tmp_path):
    """A views folder written by tvf.views.write_views: two tilted cameras over a flat 3 cm surface."""
    images = [plane_view(cam, TOP, (200, 40, 40)) for cam in CAMERAS]
    views.write_views(tmp_path, images, CAMERAS)
    return tmp_path


def edit(path, **changes):
    doc = yaml.safe_load(path.read_text())
    for key, value in changes.items():
        if value is None:
            doc.pop(key, None)
        else:
            doc[key] = value
    path.write_text(yaml.safe_dump(doc))


def test_written_views_fuse_to_the_surface_within_the_depth_quantisation(rig):
    assert sorted(p.name for p in rig.iterdir()) == [
        "a.color.png", "a.depth.png", "a.yaml", "b.color.png", "b.depth.png", "b.yaml", "workspace.yaml",
    ]  # fmt: skip
    depth = iio.imread(rig / "a.depth.png")
    assert depth.dtype == np.uint16 and 850 < np.median(depth) < 950  # millimetres
    image = views.load_rgbh(rig, views.folder_workspace(rig), "--views")
    assert image.n_views == 2 and image.coverage > 0.99
    assert np.abs(image.height - TOP).max() < 1e-3 and np.abs(image.height - TOP).mean() < 3e-4
    assert (image.color == (200, 40, 40)).all()
    assert views.read_camera(rig / "a.yaml").camera == CAMERAS[0]  # K, pose, distortion survive the file


def test_the_pose_forms_and_frames_give_the_same_camera(rig):
    path = rig / "a.yaml"
    want = views.read_camera(path).camera
    T = want.T_base_camera
    q = quaternion_xyzw(T[:3, :3])
    edit(path, T_base_camera=None, position=T[:3, 3].tolist(), orientation_xyzw=q.tolist())
    assert np.allclose(views.read_camera(path).camera.T_base_camera, T, atol=1e-12)
    edit(path, orientation_xyzw=None, orientation_wxyz=np.roll(q, 1).tolist())
    assert np.allclose(views.read_camera(path).camera.T_base_camera, T, atol=1e-12)
    body = T.copy()
    body[:3, :3] = T[:3, :3] @ views.R_BODY_OPTICAL.T  # the same camera's ROS body frame (x forward, z up)
    edit(path, orientation_wxyz=None, position=None, T_base_camera=body.tolist(), camera_frame="body")
    assert np.allclose(views.read_camera(path).camera.T_base_camera, T, atol=1e-12)


def quaternion_xyzw(R: np.ndarray) -> np.ndarray:
    """A unit quaternion (x, y, z, w) of R (w > 0 branch; fine for these test rotations)."""
    w = math.sqrt(max(1.0 + np.trace(R), 0.0)) / 2
    if w < 1e-6:  # a half turn: use the axis from the diagonal
        x = math.sqrt(max(1 + R[0, 0] - R[1, 1] - R[2, 2], 0)) / 2
        y = math.copysign(math.sqrt(max(1 - R[0, 0] + R[1, 1] - R[2, 2], 0)) / 2, R[0, 1])
        z = math.copysign(math.sqrt(max(1 - R[0, 0] - R[1, 1] + R[2, 2], 0)) / 2, R[0, 2])
        return np.array([x, y, z, w])
    return np.array(
        [(R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w), w]
    )


def test_quaternions_are_read_in_the_order_their_name_says():
    quarter = [0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)]  # +90 degrees about z, (x, y, z, w)
    assert np.allclose(views.quaternion_matrix(quarter), [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert np.allclose(views.R_BODY_OPTICAL @ [0, 0, 1], [1, 0, 0])  # optical forward = body forward (x)
    assert np.allclose(views.R_BODY_OPTICAL @ [1, 0, 0], [0, -1, 0])  # optical right = body -y (y is left)
    assert np.allclose(views.R_BODY_OPTICAL @ [0, 1, 0], [0, 0, -1])  # optical down = body -z


def test_ros_camera_info_names_and_calibration_files_are_read(rig):
    path, cam = rig / "a.yaml", CAMERAS[0]
    doc = yaml.safe_load(path.read_text())
    ros1 = {**doc, "header": {"frame_id": "a_color_optical_frame"}, "roi": {}, "R": [1, 0, 0] * 3,
            "P": [0] * 12, "binning_x": 0}  # fmt: skip
    calibration = {k: v for k, v in doc.items() if k not in ("width", "height", "K", "D")}
    calibration |= {
        "image_width": cam.width, "image_height": cam.height, "camera_name": "a",
        "camera_matrix": {"rows": 3, "cols": 3, "data": doc["K"]},
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": [0.0] * 5},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": [1, 0, 0, 0, 1, 0, 0, 0, 1]},
    }  # fmt: skip
    ros2 = {k.lower() if k in ("K", "D") else k: v for k, v in doc.items()}
    for form in (ros1, calibration, ros2):
        (rig / "a.json").write_text(json.dumps(form))
        path.unlink(missing_ok=True)
        assert views.read_camera(rig / "a.json").camera == cam


def test_float_npy_depth_and_a_custom_depth_scale_agree(rig):
    _, depth = plane_view(CAMERAS[0], TOP, (0, 0, 0))
    (rig / "a.depth.png").unlink()
    np.save(rig / "a.depth.npy", depth)
    edit(rig / "a.yaml", depth="a.depth.npy")
    edit(rig / "b.yaml", depth_scale=0.0001)  # 0.1 mm units
    _, depth_b = plane_view(CAMERAS[1], TOP, (0, 0, 0))
    (rig / "b.depth.png").write_bytes(views.depth_png_bytes(depth_b, 0.0001))
    image = views.load_rgbh(rig, WORKSPACE, "--views")
    assert np.abs(image.height - TOP).max() < 1e-4


def test_a_distorted_camera_file_is_undistorted_per_ray(rig):
    d = (-0.2, 0.05, 1e-3, -5e-4, 0.0)
    edit(rig / "a.yaml", D=list(d))
    cam = views.read_camera(rig / "a.yaml").camera
    assert cam.distortion == d
    # the pinhole image read as a distorted one comes out bent by several mm at the edges
    bent = views.fuse_views(views.read_views(rig)[:1], WORKSPACE, rig)
    assert np.abs(bent.height - TOP).max() > 3e-3
    # what the distorted camera records of the plane (pixel (v, u) sees along distort^-1 of its
    # normalised coordinates, tests/test_fusion.py) fuses flat again
    vv, uu = np.mgrid[: cam.height, : cam.width]
    x, y = fusion.undistort((uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, d)
    ray_z = (np.stack([x, y, np.ones_like(x)], -1) @ np.asarray(cam.rotation).T)[..., 2]
    (rig / "a.depth.png").write_bytes(views.depth_png_bytes((TOP - cam.position[2]) / ray_z))
    flat = views.fuse_views(views.read_views(rig)[:1], WORKSPACE, rig)
    assert np.abs(flat.height - TOP).max() < 1e-3
    edit(rig / "a.yaml", distortion_model="rational_polynomial", D=[0.0] * 8)  # zeros: a pinhole again
    assert views.read_camera(rig / "a.yaml").camera.distortion == (0.0,) * 5


BAD_CAMERA_FILES = {
    "field K is missing": {"K": None},
    "field K must be 3 x 3 numbers": {"K": [1, 2, 3]},
    "no skew": {"K": [170, 2, 120, 0, 170, 90, 0, 0, 1]},
    "focal lengths": {"K": [-170, 0, 120, 0, 170, 90, 0, 0, 1]},
    "field width must be a positive whole number": {"width": 640.5},
    "distortion_model 'equidistant' is not supported": {
        "distortion_model": "equidistant",
        "D": [0.1, 0, 0, 0],
    },
    "field D must be 5 numbers": {"D": [0.1, 0.0, 0.0]},
    "field D: the distortion cannot be inverted": {"D": [-3.0, 0, 0, 0, 0]},
    "the last row must be [0, 0, 0, 1]": {
        "T_base_camera": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]
    },
    "not a proper rotation": {"T_base_camera": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]},
    "give the pose once": {"position": [0, 0, 1], "orientation_xyzw": [0, 0, 0, 1]},
    "field T_base_camera is missing": {"T_base_camera": None},
    "not a unit quaternion": {"T_base_camera": None, "position": [0, 0, 1], "orientation_xyzw": [0, 0, 1, 1]},
    "field camera_frame must be optical": {"camera_frame": "camera_link"},
    "field depth_scale must be metres per unit": {"depth_scale": 1000},
    "unknown field 'depth_scal'": {"depth_scal": 0.001},
    "fields K and k say the same thing": {"k": [170, 0, 120, 0, 170, 90, 0, 0, 1]},
    "field T_base_camera holds NaN": {"T_base_camera": [[float("nan")] * 4] * 4},
}


@pytest.mark.parametrize("match", BAD_CAMERA_FILES)
def test_a_bad_camera_file_is_one_line_naming_the_file_and_field(rig, match):
    edit(rig / "a.yaml", **BAD_CAMERA_FILES[match])
    with pytest.raises(TvfError, match=re.escape(match)) as info:
        views.read_views(rig)
    assert str(rig / "a.yaml") in str(info.value) and "\n" not in str(info.value)


def _write(path, data: bytes) -> None:
    path.write_bytes(data)


BAD_IMAGES = {
    "the colour image is 120 x 90 but its camera file says width 640": lambda rig: _write(
        rig / "a.color.png", iio.imwrite("<bytes>", np.zeros((90, 120, 3), np.uint8), extension=".png")
    ),
    "the colour image must be 8-bit RGB": lambda rig: _write(
        rig / "a.color.png", iio.imwrite("<bytes>", np.zeros((480, 640), np.uint8), extension=".png")
    ),
    "the colour image is missing": lambda rig: (rig / "a.color.png").unlink(),
    "a PNG depth image must be 16-bit": lambda rig: _write(
        rig / "a.depth.png", iio.imwrite("<bytes>", np.ones((480, 640), np.uint8), extension=".png")
    ),
    "the depth image has shape (90, 640)": lambda rig: _write(
        rig / "a.depth.png", iio.imwrite("<bytes>", np.ones((90, 640), np.uint16), extension=".png")
    ),
    "cannot read the depth image": lambda rig: _write(rig / "a.depth.png", b"not a png"),
    "a .npy depth image holds float metres, not int64": lambda rig: (
        np.save(rig / "a.depth.npy", np.ones((480, 640), np.int64)),
        edit(rig / "a.yaml", depth="a.depth.npy"),
    ),
    "the median depth is 900 m": lambda rig: (
        np.save(rig / "a.depth.npy", np.full((480, 640), 900.0)),
        edit(rig / "a.yaml", depth="a.depth.npy"),
    ),
    "not valid YAML": lambda rig: (rig / "a.yaml").write_text("K: [1, 2\nwidth: ]"),
}


@pytest.mark.parametrize("match", BAD_IMAGES)
def test_a_bad_image_is_one_line_naming_the_file(rig, match):
    BAD_IMAGES[match](rig)
    with pytest.raises(TvfError, match=re.escape(match)) as info:
        views.read_views(rig)
    assert str(rig / "a.") in str(info.value) and "\n" not in str(info.value)


def test_views_that_miss_the_workspace_and_empty_folders_are_refused(rig, tmp_path_factory):
    edit(rig / "a.yaml", T_base_camera=np.eye(4).tolist())  # optical z up from the base: sees nothing
    edit(rig / "b.yaml", T_base_camera=np.eye(4).tolist())
    with pytest.raises(TvfError, match="no depth reading of any view falls in the workspace"):
        views.load_rgbh(rig, WORKSPACE, "--views")
    empty = tmp_path_factory.mktemp("empty")
    with pytest.raises(TvfError, match="holds no camera file"):
        views.read_views(empty)
    with pytest.raises(TvfError, match="give a folder of views or an .npz"):
        views.load_rgbh(empty / "scene.png", WORKSPACE, "--views")


def test_workspace_files_set_the_bounds_and_are_checked(tmp_path):
    path = tmp_path / "workspace.yaml"
    path.write_text("x_min: 0.3\nx_max: 0.8\n")
    ws = views.read_workspace(path)
    assert (ws.x_min, ws.x_max, ws.y_min, ws.pixel_size) == (0.3, 0.8, WORKSPACE.y_min, WORKSPACE.pixel_size)
    assert views.folder_workspace(tmp_path) == ws and views.folder_workspace(tmp_path / "none") == WORKSPACE
    for text, match in (
        ("x_mn: 0.3\n", "unknown field 'x_mn'"),
        ("x_max: 0.2\n", "field x_max must be above x_min"),
        ("pixel_size: 0.003\n", "does not divide"),
        ("z_max: high\n", "field z_max must be a number"),
    ):
        path.write_text(text)
        with pytest.raises(TvfError, match=re.escape(match)):
            views.read_workspace(path)


def test_saved_rgbh_images_are_read_and_checked(tmp_path):
    color, height = np.zeros((160, 160, 3), np.uint8), np.full((160, 160), 0.02, np.float32)
    (tmp_path / "goal.npz").write_bytes(views.rgbh_bytes(color, height))
    image = views.load_rgbh(tmp_path / "goal.npz", WORKSPACE, "--goal")
    assert image.n_views == 0 and np.array_equal(image.height, height)
    for arrays, match in (
        ({"color": color}, "field height is missing"),
        ({"color": color, "height": height[:80]}, "field height must be float metres of shape (160, 160)"),
        ({"color": color.astype(np.float32), "height": height}, "field color must be uint8"),
        ({"color": color, "height": np.full((160, 160), np.nan)}, "holds NaN"),
    ):
        np.savez(tmp_path / "bad.npz", **arrays)
        with pytest.raises(TvfError, match=re.escape(match)):
            views.read_rgbh(tmp_path / "bad.npz")


def test_holes_are_filled_as_the_simulator_fills_them_unless_told(rig):
    assert (
        views.resolve_hole_fill("auto", 1) == "background" and views.resolve_hole_fill("auto", 3) == "nearest"
    )
    assert views.resolve_hole_fill("nearest", 1) == "nearest"
    with pytest.raises(
        TvfError, match="unknown hole filling 'blur'; choose one of auto, nearest, background"
    ):
        views.resolve_hole_fill("blur", 2)
    both, one = views.read_views(rig), views.read_views(rig)[:1]
    assert views.fuse_views(both, WORKSPACE, rig).hole_fill == "nearest"
    assert views.load_rgbh(rig, WORKSPACE, "--views", "background").hole_fill == "background"
    depth = iio.imread(rig / "a.depth.png")
    depth[220:260, 300:360] = 0  # no reading there: a hole in the fused map
    iio.imwrite(rig / "a.depth.png", depth)
    one = views.read_views(rig)[:1]
    single = views.fuse_views(one, WORKSPACE, rig)
    assert single.hole_fill == "background" and single.coverage < 0.99
    told = views.fuse_views(one, WORKSPACE, rig, "nearest")
    assert told.hole_fill == "nearest" and np.allclose(told.height, single.height)  # a flat scene: the same
