"""The depth-camera model on synthetic images: noise level, seeding, dropout at silhouettes, quantisation,
calibration errors and bad configurations (no rendering)."""

import dataclasses
import math

import numpy as np
import pytest

from tvf.errors import TvfError
from tvf.fusion import PinholeCamera, TableLevelError, fuse_with_coverage, level_on_table, table_plane
from tvf.sim.sensors import (
    SENSORS,
    SensorConfig,
    calibration_error,
    corrupt_view,
    get_sensor,
    perturb_camera,
    silhouettes,
    view_rng,
)

RGB = np.full((120, 160, 3), 100, np.uint8)


def flat(depth: float = 0.8, shape=(120, 160)) -> np.ndarray:
    return np.full(shape, depth, np.float32)


def square(inner: float = 0.76, outer: float = 0.8) -> np.ndarray:
    d = flat(outer)
    d[40:80, 60:100] = inner
    return d


def test_the_noise_has_the_configured_sigma_at_a_known_depth():
    cfg = SensorConfig(sigma_1m=0.00145)
    for depth in (0.5, 0.8, 1.2):
        _, noisy = corrupt_view(RGB, flat(depth, (200, 200)), cfg, view_rng(1, 0, 0, 0))
        err = noisy.astype(np.float64) - np.float32(depth)
        assert abs(err.mean()) < 0.05 * cfg.sigma(depth)
        assert err.std() == pytest.approx(0.00145 * depth**2, rel=0.03)
    floor = SensorConfig(sigma_1m=0.001, sigma_floor=0.0005)
    assert floor.sigma(np.array(2.0)) == pytest.approx(0.0045)


def test_draws_are_seeded_by_episode_step_and_camera():
    cfg = SENSORS["d415"]
    first = corrupt_view(RGB, square(), cfg, view_rng(7, 0, 2, 1))
    again = corrupt_view(RGB, square(), cfg, view_rng(7, 0, 2, 1))
    assert all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))
    for other in (view_rng(9, 0, 2, 1), view_rng(7, 1, 2, 1), view_rng(7, 0, 3, 1), view_rng(7, 0, 2, 0)):
        assert not np.array_equal(first[1], corrupt_view(RGB, square(), cfg, other)[1])
    state = np.random.get_state()
    corrupt_view(RGB, square(), cfg, view_rng(7, 0, 2, 1))
    assert np.array_equal(np.random.get_state()[1], state[1])  # the global RNG is never used


def test_dropout_appears_at_silhouettes():
    d = square()
    edge = silhouettes(d, 0.01)
    assert edge[39, 70] and edge[40, 70] and edge[60, 59] and edge[60, 60]  # both sides of the jump
    assert not edge[60, 80] and not edge[10, 10]
    assert edge.sum() == 4 * 40 + (4 * 40 - 4)  # the ring outside the square and the ring inside it
    assert silhouettes(d, 0.01, width=3).sum() > edge.sum()
    _, out = corrupt_view(RGB, d, SensorConfig(edge_dropout=1.0), view_rng(0, 0, 0, 0))
    assert (out[edge] == 0).all() and (out[~edge] > 0).all()
    _, half = corrupt_view(RGB, d, SensorConfig(edge_dropout=0.5), view_rng(0, 0, 0, 0))
    assert 0.35 < (half[edge] == 0).mean() < 0.65 and (half[~edge] > 0).all()


def test_random_dropout_rate_quantisation_and_missing_readings():
    d = flat()
    d[0, :5] = 0.0
    d[1, :5] = np.nan
    _, out = corrupt_view(RGB, d, SensorConfig(dropout=0.1), view_rng(0, 0, 0, 0))
    assert (out[:2, :5] == 0).all() and not np.isnan(out).any()
    assert (out == 0).mean() == pytest.approx(0.1, abs=0.01)
    _, q = corrupt_view(RGB, flat(0.8004), SensorConfig(depth_unit=0.001), view_rng(0, 0, 0, 0))
    assert np.allclose(q, 0.800)


def test_colour_noise_stays_in_range():
    rgb = np.zeros((50, 50, 3), np.uint8)
    rgb[:25] = 255
    out, _ = corrupt_view(rgb, flat(0.8, (50, 50)), SensorConfig(color_sigma=5.0), view_rng(0, 0, 0, 0))
    assert out.dtype == np.uint8 and not np.array_equal(out, rgb)
    mid = corrupt_view(np.full_like(rgb, 128), flat(0.8, (50, 50)), SensorConfig(color_sigma=5.0),
                       view_rng(0, 0, 0, 0))[0]  # fmt: skip
    assert mid.astype(float).std() == pytest.approx(5.0, rel=0.05)
    assert 0 < out[25:].max() < 40 and 215 < out[:25].min() < 255  # clipped at 0 and 255, not wrapped


def test_the_ideal_sensor_returns_its_inputs():
    ideal = get_sensor("ideal")
    views, cams = [(RGB, flat())], (nadir(),)
    out_views, out_cams = ideal.apply(views, cams, seed=3, step=0, stream=0)
    assert out_views[0][0] is RGB and out_views[0][1] is views[0][1] and out_cams == cams
    assert ideal.ideal and ideal == SensorConfig() and not SENSORS["d415"].ideal


# ---------------------------------------------------------------------------- calibration


def nadir(height: float = 1.0) -> PinholeCamera:
    """A camera 1 m above the workspace centre looking straight down (image x = base x)."""
    R = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    return PinholeCamera("nadir", 320, 320, 400.0, 400.0, 159.5, 159.5, R, (0.5, 0.0, height))


def block_scene(cam: PinholeCamera) -> np.ndarray:
    """Depth of a flat table with a 4 cm cube (top at z = 0.04) at x 0.45-0.49, y -0.02-0.02."""
    u, v = np.meshgrid((np.arange(cam.width) - cam.cx) / cam.fx, (np.arange(cam.height) - cam.cy) / cam.fy)
    x, y = cam.position[0] + u * (cam.position[2] - 0.04), cam.position[1] - v * (cam.position[2] - 0.04)
    on_top = (x >= 0.45) & (x < 0.49) & (y >= -0.02) & (y < 0.02)
    return np.where(on_top, cam.position[2] - 0.04, cam.position[2]).astype(np.float32)


def fused_height(cam_render: PinholeCamera, cam_fuse: PinholeCamera) -> np.ndarray:
    depth = block_scene(cam_render)
    _, height, _ = fuse_with_coverage([(np.zeros((*depth.shape, 3), np.uint8), depth)], [cam_fuse])
    return height


def test_a_translation_error_shifts_the_fused_map_by_that_much():
    cam = nadir()
    true = fused_height(cam, cam)
    assert true.max() == pytest.approx(0.04, abs=1e-6) and np.median(true) == pytest.approx(0.0, abs=1e-6)
    up = fused_height(cam, perturb_camera(cam, (0.0, 0.0, 0.005), (0.0, 0.0, 0.0)))
    assert np.median(up) == pytest.approx(0.005, abs=1e-6) and up.max() == pytest.approx(0.045, abs=1e-6)
    moved = fused_height(cam, perturb_camera(cam, (0.00625, 0.0, 0.0), (0.0, 0.0, 0.0)))  # 2 pixels in x
    cols = lambda h: np.nonzero(h > 0.02)[1].mean()  # noqa: E731
    assert cols(moved) - cols(true) == pytest.approx(2.0, abs=0.05)


def test_a_rotation_error_tilts_the_table():
    cam, beta = nadir(), math.radians(1.0)
    lifted = perturb_camera(cam, (0.0, 0.0, 0.01), (0.0, beta, 0.0))  # lifted so no point drops below z_min
    height = fused_height(cam, lifted)
    table = height < 0.02
    rows, cols = np.nonzero(table)
    A = np.stack([cols * 0.003125, rows * 0.003125, np.ones(len(cols))], axis=1)
    slope_x, slope_y, _ = np.linalg.lstsq(A, height[table], rcond=None)[0]
    assert slope_x == pytest.approx(-math.tan(beta), rel=0.02) and abs(slope_y) < 1e-4


def test_calibration_errors_have_the_configured_size_and_draw_rule():
    cfg = SENSORS["d415-one-calib"]
    t, r = calibration_error(cfg, seed=5, camera=0)
    assert np.linalg.norm(t) == pytest.approx(0.003) and np.degrees(np.linalg.norm(r)) == pytest.approx(1.0)
    assert not np.allclose(t, calibration_error(cfg, seed=7, camera=0)[0])
    fixed = SensorConfig(calib_translation=0.003, calib_draw="fixed")
    assert np.allclose(calibration_error(fixed, 5, 0)[0], calibration_error(fixed, 7, 0)[0])
    moved = perturb_camera(nadir(), t, r)
    angle = np.arccos((np.trace(np.asarray(moved.rotation) @ np.asarray(nadir().rotation).T) - 1) / 2)
    assert np.degrees(angle) == pytest.approx(1.0, rel=1e-6)


# ---------------------------------------------------------------------------- table levelling


def angle_between(a: PinholeCamera, b: PinholeCamera) -> float:
    """Degrees between two cameras' orientations."""
    cos = (np.trace(np.asarray(a.rotation) @ np.asarray(b.rotation).T) - 1) / 2
    return math.degrees(math.acos(min(1.0, cos)))


def test_levelling_undoes_a_tilt_and_a_height_error_exactly():
    cam = nadir()
    believed = perturb_camera(cam, (0.0, 0.0, 0.004), (math.radians(0.8), math.radians(-0.6), 0.0))
    depth = block_scene(cam)  # the world renders from the true pose; the block is 2.5 % of the points
    normal, _ = table_plane(depth, believed)
    assert math.degrees(math.acos(normal[2])) == pytest.approx(1.0, abs=1e-3)  # the believed table tilts
    levelled = level_on_table(depth, believed)
    assert angle_between(levelled, cam) < 1e-6 and np.allclose(levelled.position, cam.position, atol=1e-7)
    assert np.abs(fused_height(cam, levelled) - fused_height(cam, cam)).max() < 1e-5


def test_levelling_keeps_what_a_plane_cannot_see():
    cam = nadir()
    believed = perturb_camera(cam, (0.002, -0.001, 0.0), (0.0, 0.0, math.radians(1.0)))  # shift and yaw
    levelled = level_on_table(block_scene(cam), believed)
    assert angle_between(levelled, believed) < 1e-6 and np.allclose(levelled.position, believed.position)


def test_levelling_leaves_the_base_top_out_of_the_fit():
    cam = nadir()
    depth = block_scene(cam)
    u = (np.arange(cam.width) - cam.cx) / cam.fx
    depth[:, u * cam.position[2] + cam.position[0] > 0.6] = cam.position[2] - 0.005  # a 5 mm base, x > 0.6
    believed = perturb_camera(cam, (0.0, 0.0, 0.003), (0.0, math.radians(0.5), 0.0))
    levelled = level_on_table(depth, believed)
    assert angle_between(levelled, cam) < 1e-3 and levelled.position[2] == pytest.approx(1.0, abs=1e-5)


def test_a_camera_that_sees_no_table_is_a_one_line_error():
    cam = nadir()
    with pytest.raises(TableLevelError, match="points lie within 20 mm of the table plane") as err:
        level_on_table(flat(0.5, (cam.height, cam.width)), cam)  # a surface 50 cm above the table
    assert "\n" not in str(err.value) and "nadir" in str(err.value)


def test_the_levelled_preset_levels_the_miscalibrated_camera():
    cfg = SENSORS["d415-one-calib-level"]
    assert cfg.level_table and not cfg.ideal and replace_level(cfg, False) == SENSORS["d415-one-calib"]
    cam = nadir()
    depth = block_scene(cam)
    _, (calib,) = SENSORS["d415-one-calib"].apply([(RGB, depth)], [cam], seed=5, step=0, stream=0)
    _, (levelled,) = cfg.apply([(RGB, depth)], [cam], seed=5, step=0, stream=0)
    assert angle_between(calib, cam) > 0.99 and angle_between(levelled, cam) < angle_between(calib, cam)


def test_the_two_sided_goal_preset_changes_the_goal_rig_only():
    cfg = SENSORS["d415-one-goal2"]
    assert (cfg.cameras, cfg.goal_rig) == ("one", "two") and SENSORS["d415-one"].goal_rig == "one"
    assert dataclasses.replace(cfg, name="d415-one", goal_cameras=None) == SENSORS["d415-one"]


def test_the_back_pose_mirrors_the_front_camera_across_the_workspace_centre():
    from tvf.sim.camera import ONE_CAMERA, ONE_CAMERA_BACK

    centre = np.array([0.5, 0.0, 0.0])
    for cam in (ONE_CAMERA, ONE_CAMERA_BACK):
        to_centre = centre - np.asarray(cam.position)
        axis = cam.rotation @ [0.0, 0.0, 1.0]
        assert np.allclose(axis, to_centre / np.linalg.norm(to_centre), atol=1e-9)  # it looks at the centre
        assert np.isclose(np.linalg.norm(to_centre), 0.8) and np.isclose(np.degrees(np.arcsin(-axis[2])), 60)
    mirror = np.diag([-1.0, 1.0, 1.0])  # x -> 1 - x about the centre's plane x = 0.5
    front, back = (np.asarray(cam.position) - centre for cam in (ONE_CAMERA, ONE_CAMERA_BACK))
    assert np.allclose(mirror @ front, back)
    # each image's "down" is the mirror of the other's: one image is the other's view turned round
    assert np.allclose(mirror @ ONE_CAMERA.rotation[:, 1], ONE_CAMERA_BACK.rotation[:, 1])


def replace_level(cfg: SensorConfig, level: bool) -> SensorConfig:
    return dataclasses.replace(cfg, name="d415-one-calib", level_table=level)


# ---------------------------------------------------------------------------- bad configurations


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"sigma_1m": -0.001}, "sigma_1m must be a finite number >= 0"),
        ({"depth_unit": float("nan")}, "depth_unit must be a finite number >= 0"),
        ({"dropout": 1.5}, "dropout is a probability in [0, 1]"),
        ({"cameras": "four"}, "cameras must be one of three, one, two, not 'four'"),
        ({"goal_cameras": "front"}, "goal_cameras must be one of three, one, two or None, not 'front'"),
        ({"edge_width": 0}, "edge_width must be an integer >= 1"),
        ({"calib_draw": "sometimes"}, "calib_draw must be 'episode' or 'fixed'"),
        ({"hole_fill": "blur"}, "hole_fill must be one of nearest, background, not 'blur'"),
        ({"level_table": "yes"}, "level_table must be true or false, not 'yes'"),
    ],
)
def test_bad_values_are_one_line_errors(kwargs, words):
    with pytest.raises(TvfError) as err:
        SensorConfig(**kwargs)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_an_unknown_preset_names_the_choices():
    with pytest.raises(TvfError, match="unknown sensor 'd999'; choose one of ideal, one, d415"):
        get_sensor("d999")


def test_one_camera_presets_fill_holes_from_the_background_and_three_camera_ones_from_the_nearest():
    fills = {name: (cfg.cameras, cfg.hole_fill) for name, cfg in SENSORS.items()}
    assert all(fill == ("background" if rig == "one" else "nearest") for rig, fill in fills.values())
    assert fills["d415-one"] == ("one", "background") and SensorConfig().hole_fill == "nearest"
