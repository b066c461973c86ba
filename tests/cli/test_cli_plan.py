"""`tvf render --export-views` and `tvf plan`: the simulator's cameras as a real rig's files, and planning
from them gives the simulator's height map and the simulator's action."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from cli_run import run

import tvf
from tvf.errors import TvfError
from tvf.geometry import WORKSPACE, pixel_to_world
from tvf.views import load_rgbh

SCENES = (("stack-tower", 3), ("put-t", 1))
"""A training task and an unseen one (scene seeds)."""


@pytest.fixture(scope="module")
def rigs(tmp_path_factory):
    """Per scene: `tvf render` output (initial.npz and goal.npz are the simulator's own images) with the
    exported views in OUT/rig/scene and OUT/rig/goal."""
    out = {}
    for task, seed in SCENES:
        folder = tmp_path_factory.mktemp(task)
        code = run_quiet("render", "--task", task, "--seed", str(seed), "--out", str(folder),
                         "--export-views", str(folder / "rig"))  # fmt: skip
        assert code == 0
        out[task] = folder
    return out


def run_quiet(*args: str) -> int:
    from tvf.cli import main

    try:
        main(list(args))
    except SystemExit as exc:
        return int(exc.code or 0)
    return 0


def simulator_images(folder, name: str) -> tuple[np.ndarray, np.ndarray]:
    with np.load(folder / f"{name}.npz") as data:
        return data["color"], data["height"]


@pytest.mark.parametrize("task", [t for t, _ in SCENES])
def test_exported_views_give_the_simulators_height_map_within_1mm(rigs, task):
    folder = rigs[task]
    for name, views in (("initial", "scene"), ("goal", "goal")):
        color, height = simulator_images(folder, name)
        image = load_rgbh(folder / "rig" / views, WORKSPACE, "--views")
        assert image.n_views == 3 and image.coverage > 0.98
        mae = float(np.abs(image.height - height).mean())
        assert mae < 1e-3, f"{task} {name}: height MAE {1000 * mae:.3f} mm"
        assert np.abs(image.color.astype(int) - color).mean() < 1.0  # colour PNGs are lossless
    camera = yaml.safe_load((folder / "rig" / "scene" / "front.yaml").read_text())
    assert (
        camera["K"][2] == camera["width"] / 2 and camera["K"][5] == camera["height"] / 2 - 1
    )  # TinyRenderer


def test_float_depth_files_give_the_simulators_images_bit_for_bit(tmp_path):
    """The file path and the simulator call the same fusion: with unrounded depth they agree exactly."""
    from tvf.sim.env import TvfEnv
    from tvf.views import write_views

    env = TvfEnv("put-t")
    try:
        obs, info = env.reset(seed=1)
        for name, (images, cameras), want in (
            ("scene", env.world.views(), obs),
            ("goal", env.goal_views, info["goal"]),
        ):
            folder = tmp_path / name
            write_views(folder, images, cameras)
            for (_, depth), cam in zip(images, cameras, strict=True):
                (folder / f"{cam.name}.depth.png").unlink()
                np.save(folder / f"{cam.name}.depth.npy", depth)  # found by its default name
                doc = yaml.safe_load((folder / f"{cam.name}.yaml").read_text())
                del doc["depth"]
                (folder / f"{cam.name}.yaml").write_text(yaml.safe_dump(doc))
            image = load_rgbh(folder, WORKSPACE, "--views")
            assert np.array_equal(image.height, want["height"]) and np.array_equal(image.color, want["color"])
    finally:
        env.close()


def test_finer_depth_units_are_recorded_and_bring_the_map_closer(rigs, tmp_path, capsys):
    folder, fine = rigs["put-t"], tmp_path / "fine"
    code, _, err = run(capsys, "render", "--task", "put-t", "--seed", "1", "--out", str(fine),
                       "--export-views", str(fine / "rig"), "--depth-scale", "0.0001")  # fmt: skip
    assert code == 0, err
    assert yaml.safe_load((fine / "rig" / "scene" / "front.yaml").read_text())["depth_scale"] == 0.0001
    _, height = simulator_images(folder, "initial")
    errors = [np.abs(load_rgbh(f / "rig" / "scene", WORKSPACE, "--views").height - height).mean()
              for f in (folder, fine)]  # fmt: skip
    assert errors[1] < errors[0] / 3  # 0.1 mm units against mm units
    code, _, err = run(capsys, "render", "--task", "put-t", "--out", str(tmp_path / "bad"),
                       "--depth-scale", "1")  # fmt: skip
    assert code == 2 and "--depth-scale is metres per unit" in err and len(err.strip().splitlines()) == 1


def simulator_decision(folder) -> tvf.Decision:
    """Planning inside the simulator: the GCTN on the simulator's own fused images."""
    obs, goal = simulator_images(folder, "initial"), simulator_images(folder, "goal")
    return tvf.load_planner("gctn").next_action(*obs, *goal)


@pytest.mark.parametrize("task", [t for t, _ in SCENES])
def test_plan_on_exported_views_takes_the_simulators_action(capsys, rigs, tmp_path, task):
    folder = rigs[task]
    rig = folder / "rig"
    code, out, err = run(capsys, "plan", "--method", "gctn", "--views", str(rig / "scene"),
                         "--goal", str(rig / "goal"), "--out", str(tmp_path))  # fmt: skip
    assert code == 0, err
    record = json.loads((tmp_path / "decision.json").read_text())
    want = simulator_decision(folder)
    assert (
        tuple(record["pick"]["pixel"]) == want.pick_pixel
        and tuple(record["place"]["pixel"]) == want.place_pixel
    )
    assert record["rotation_bin"] == want.rotation_bin and record["n_rotations"] == 36
    for name in ("pick", "place"):
        pose = record[name]
        np.testing.assert_allclose([pose["x"], pose["y"]], pixel_to_world(np.array(pose["pixel"])))
        T = np.array(pose["T_base_tool"])
        c, s = np.cos(pose["yaw"]), np.sin(pose["yaw"])
        np.testing.assert_allclose(T[:3, 3], [pose["x"], pose["y"], pose["z"]])
        np.testing.assert_allclose(T[:2, :2], [[c, -s], [s, c]], atol=1e-12)
    assert abs(record["pick"]["z"] - want.pick[2]) < 3e-3  # heights from the fused files, within mm
    assert record["scene"]["views"] == 3 and "robot base frame" in record["convention"]
    assert record["scene"]["hole_fill"] == record["goal"]["hole_fill"] == "nearest"  # three cameras: auto
    assert (tmp_path / "decision.png").read_bytes()[:4] == b"\x89PNG"
    saved = load_rgbh(tmp_path / "scene.npz", WORKSPACE, "--views")
    assert np.array_equal(saved.height, load_rgbh(rig / "scene", WORKSPACE, "--views").height)


def test_plan_can_foresee_without_a_network(capsys, rigs, tmp_path):
    rig = rigs["put-t"] / "rig"
    args = ("plan", "--method", "tvf-large-no-image-rules", "--views", str(rig / "scene"), "--goal",
            str(rig / "goal"), "--foresight", "rigid")  # fmt: skip
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "rigid"))
    assert code == 0, err
    record = json.loads((tmp_path / "rigid" / "decision.json").read_text())
    assert set(record) >= {"pick", "place"} and (tmp_path / "rigid" / "decision.png").is_file()
    code, _, err = run(capsys, *args, "--vf", str(tmp_path / "vf.pt"), "--out", str(tmp_path / "both"))
    assert code == 2 and err.strip().count("\n") == 0 and "drop --vf" in err
    code, _, err = run(capsys, *args[:-1], "simulator", "--out", str(tmp_path / "sim"))
    assert code == 2 and "simulator" in err and not (tmp_path / "sim").exists()


def test_a_saved_goal_image_and_a_moved_rig_give_the_same_pixels(capsys, rigs, tmp_path):
    folder = rigs["put-t"]
    want = simulator_decision(folder)
    # the goal as an RGB-H .npz (what `tvf render` writes)
    code, _, err = run(capsys, "plan", "--method", "gctn", "--views", str(folder / "rig" / "scene"),
                       "--goal", str(folder / "goal.npz"), "--out", str(tmp_path / "npz"))  # fmt: skip
    assert code == 0, err
    record = json.loads((tmp_path / "npz" / "decision.json").read_text())
    assert tuple(record["place"]["pixel"]) == want.place_pixel and record["goal"]["views"] == 0
    # the whole rig and its workspace 1 cm further along y in the base frame: same pixels, poses moved
    moved = tmp_path / "moved"
    moved.mkdir()
    for path in (folder / "rig" / "scene").iterdir():
        (moved / path.name).write_bytes(path.read_bytes())
    for path in moved.glob("*.yaml"):
        doc = yaml.safe_load(path.read_text())
        if path.stem == "workspace":
            doc["y_min"], doc["y_max"] = doc["y_min"] + 0.01, doc["y_max"] + 0.01
        else:
            doc["T_base_camera"][1][3] += 0.01
        path.write_text(yaml.safe_dump(doc))
    code, _, err = run(capsys, "plan", "--method", "gctn", "--views", str(moved),
                       "--goal", str(folder / "goal.npz"), "--out", str(tmp_path / "moved-out"))  # fmt: skip
    assert code == 0, err
    shifted = json.loads((tmp_path / "moved-out" / "decision.json").read_text())
    assert shifted["pick"]["pixel"] == record["pick"]["pixel"]
    assert shifted["place"]["pixel"] == record["place"]["pixel"]
    assert shifted["place"]["y"] == pytest.approx(record["place"]["y"] + 0.01, abs=1e-9)
    assert shifted["place"]["x"] == pytest.approx(record["place"]["x"], abs=1e-9)
    code, _, err = run(capsys, "plan", "--method", "gctn", "--views", str(moved),
                       "--goal", str(folder / "rig" / "goal"), "--out", str(tmp_path / "mixed"))  # fmt: skip
    assert code == 2 and "recorded with another workspace" in err and err.count("\n") == 1


def tilted_copy(src, dst, degrees: float, lift: float) -> None:
    """The views folder ``src`` with every camera file's pose turned by ``degrees`` about the base x axis
    through the camera and lifted by ``lift`` m: a calibration a degree and a few mm off."""
    from tvf.geometry import rotation_matrix

    dst.mkdir()
    for path in src.iterdir():
        (dst / path.name).write_bytes(path.read_bytes())
    for path in dst.glob("*.yaml"):
        doc = yaml.safe_load(path.read_text())
        if "T_base_camera" in doc:
            T = np.asarray(doc["T_base_camera"], dtype=float)
            T[:3, :3] = rotation_matrix([np.radians(degrees), 0.0, 0.0]) @ T[:3, :3]
            T[2, 3] += lift
            doc["T_base_camera"] = T.tolist()
            path.write_text(yaml.safe_dump(doc))


def test_levelling_on_the_table_undoes_a_tilted_calibration(capsys, rigs, tmp_path):
    folder = rigs["put-t"]
    _, height = simulator_images(folder, "initial")
    for name, views in (("scene", "scene"), ("goal", "goal")):
        tilted_copy(folder / "rig" / views, tmp_path / name, degrees=1.0, lift=0.005)
    off = load_rgbh(tmp_path / "scene", WORKSPACE, "--views")
    levelled = load_rgbh(tmp_path / "scene", WORKSPACE, "--views", level_table=True)
    assert np.abs(off.height - height).mean() > 0.003  # measured: about 6 mm
    assert np.abs(levelled.height - height).mean() < 0.001
    assert [c["camera"] for c in levelled.levelling] == ["front", "left", "right"] and not off.levelling
    corrections = levelled.levelling
    assert all(c["lift_mm"] < -3 and 0.5 < c["tilt_deg"] < 1.5 for c in corrections), corrections
    code, _, err = run(capsys, "plan", "--method", "gctn", "--views", str(tmp_path / "scene"), "--goal",
                       str(tmp_path / "goal"), "--level-table", "--out", str(tmp_path / "out"))  # fmt: skip
    assert code == 0, err
    record = json.loads((tmp_path / "out" / "decision.json").read_text())
    want = simulator_decision(folder).place_pixel  # within a pixel: the depth files hold whole mm
    assert np.abs(np.subtract(record["place"]["pixel"], want)).max() <= 1, (record["place"], want)
    assert len(record["scene"]["levelling"]) == 3 and len(record["goal"]["levelling"]) == 3
    tilted_copy(folder / "rig" / "scene", tmp_path / "high", degrees=0.0, lift=0.5)  # sees no table
    code, _, err = run(capsys, "plan", "--method", "gctn", "--views", str(tmp_path / "high"), "--goal",
                       str(folder / "goal.npz"), "--level-table", "--out", str(tmp_path / "o2"))  # fmt: skip
    assert code == 2 and "high: camera" in err and "of the table plane" in err and err.count("\n") == 1


def test_actions_outside_the_reach_and_unusable_workspaces_are_refused(capsys, rigs, tmp_path):
    folder = rigs["stack-tower"]
    far = tmp_path / "far.yaml"
    far.write_text("x_min: 0.65\nx_max: 1.15\n")  # every pose > 0.65 m from the base; reach ends at 0.72
    goal, out = str(folder / "goal.npz"), str(tmp_path / "o")
    code, _, err = run(capsys, "plan", "--method", "gctn", "--views", str(folder / "initial.npz"),
                       "--goal", goal, "--workspace", str(far), "--out", out)  # fmt: skip
    assert code == 2 and "outside the arm's reach 0.3-0.72 m" in err and err.count("\n") == 1
    assert not (tmp_path / "o" / "decision.json").exists()
    coarse = tmp_path / "coarse.yaml"
    coarse.write_text("x_max: 1.25\ny_max: 0.75\npixel_size: 0.00625\n")
    code, _, err = run(capsys, "plan", "--views", str(folder / "rig" / "scene"), "--goal", goal,
                       "--workspace", str(coarse), "--out", out)  # fmt: skip
    assert code == 2 and "planners take 160 x 160 pixels of 3.125 mm" in err
    code, _, err = run(capsys, "plan", "--views", str(tmp_path / "nowhere"), "--goal", goal, "--out", out)
    assert code == 2 and "give a folder of views or an .npz" in err


def test_poses_are_checked_against_the_workspace_and_the_reach_ring():
    from tvf.cli.plan import refuse_unreachable, to_base_frame

    refuse_unreachable("pick", np.array([0.45, 0.1, 0.02, 0.0]), WORKSPACE)  # 0.46 m from the base: fine
    for pose, match in (
        ((0.26, 0.0, 0.02, 0.0), "is 0.260 m from the robot base"),  # in the workspace, inside the inner ring
        ((0.74, 0.24, 0.02, 0.0), "is 0.778 m from the robot base"),  # a corner beyond the reach
        ((0.5, 0.3, 0.02, 0.0), "outside the workspace"),
        ((0.5, 0.0, 0.5, 0.0), "outside the workspace"),
    ):
        with pytest.raises(TvfError, match=match):
            refuse_unreachable("place", np.array(pose), WORKSPACE)
    moved = type(WORKSPACE)(z_min=0.1, z_max=0.38)
    assert to_base_frame(np.zeros((2, 4)), moved)[:, 2].tolist() == [0.1, 0.1]


SLOW_DECISIONS = 20


TVF_NEAR_TIES = pytest.mark.xfail(
    reason="measured: TVF-L takes the same action on 14-15 of 20 (70-75 %; 85 % with 0.1 mm depth units): "
    "its search flips between near-equal scores on sub-millimetre height changes (issue 13, item 5)",
    strict=False,
)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["gctn", pytest.param("tvf-large", marks=TVF_NEAR_TIES)])
def test_exported_views_agree_with_the_simulator_on_20_unseen_decisions(tmp_path, method):
    """The first decision of 20 unseen-task episodes (validation seeds), planned inside the simulator and
    from its exported files (16-bit mm depth): the same pick and place pixel and rotation bin on >= 95%
    (issue 13's target). Measured once: GCTN 19 of 20; height MAE 0.21-0.24 mm."""
    from tvf.sim.env import TvfEnv
    from tvf.tasks import load_tasks
    from tvf.views import folder_workspace, write_views

    tasks = load_tasks().resolve("unseen")
    planner = tvf.load_planner(method)
    agree, maes = [], []
    for i in range(SLOW_DECISIONS):
        task, seed = tasks[i % len(tasks)], 1 + 2 * (i // len(tasks))
        env = TvfEnv(task)
        try:
            obs, info = env.reset(seed=seed)
            rig = tmp_path / f"{task.name}-{seed}"
            write_views(rig / "scene", *env.world.views())
            write_views(rig / "goal", *env.goal_views)
        finally:
            env.close()
        goal = info["goal"]
        ws = folder_workspace(rig / "scene")
        scene_img, goal_img = load_rgbh(rig / "scene", ws, "--views"), load_rgbh(rig / "goal", ws, "--goal")
        maes.append(float(np.abs(scene_img.height - obs["height"]).mean()))
        inside = planner.next_action(obs["color"], obs["height"], goal["color"], goal["height"])
        outside = planner.next_action(scene_img.color, scene_img.height, goal_img.color, goal_img.height)
        same = (inside.pick_pixel, inside.place_pixel, inside.rotation_bin) == (
            outside.pick_pixel, outside.place_pixel, outside.rotation_bin)  # fmt: skip
        agree.append(same)
        print(f"{method} {task.name} seed {seed}: MAE {1000 * maes[-1]:.3f} mm, same action {same}")
    rate = float(np.mean(agree))
    print(
        f"{method}: agreement {rate:.0%} of {SLOW_DECISIONS}, height MAE mean {1000 * np.mean(maes):.3f} mm"
    )
    assert max(maes) < 1e-3 and rate >= 0.95
