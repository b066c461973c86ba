"""`tvf plan`: the next pick and place from a real rig's files (calibrated RGB-D views), in the base frame."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from tvf.cli.common import check_output_dir
from tvf.errors import TvfError
from tvf.geometry import REACH, WORKSPACE, Workspace

POSE_CONVENTION = (
    "x, y, z in metres and yaw in radians about the base z axis, in the robot base frame (the frame of "
    "every camera file's T_base_camera). T_base_tool is the same pose as a 4 x 4: translation (x, y, z), "
    "rotation yaw about z, its z axis up; for a tool frame whose z points down (the approach direction) "
    "use T_base_tool @ diag(1, -1, -1, 1). z is the suction cup's tip: the top of the block at the pick, "
    "the top of the placed block at the place; yaw of the place minus yaw of the pick is the block's turn."
)


def check_grid(ws: Workspace, source: str) -> None:
    """Refuse a workspace the shipped models cannot see: they take 160 x 160 pixels of 3.125 mm."""
    if ws.shape != WORKSPACE.shape or not math.isclose(ws.pixel_size, WORKSPACE.pixel_size):
        mm, want = 1000 * ws.pixel_size, 1000 * WORKSPACE.pixel_size
        raise TvfError(
            f"{source}: the workspace is {ws.rows} x {ws.cols} pixels of {mm:g} mm, but the planners take "
            f"{WORKSPACE.rows} x {WORKSPACE.cols} pixels of {want:g} mm; move the bounds, keep their size "
            "(0.5 x 0.5 m) and pixel_size 0.003125"
        )


def to_base_frame(action: np.ndarray, ws: Workspace) -> np.ndarray:
    """The planner's ``(2, 4)`` action (on the default workspace grid) on the grid of ``ws``: the same pixels
    and heights, moved by the offset between the two workspaces' corners (same size, same pixel size)."""
    shift = np.array(
        [ws.x_min - WORKSPACE.x_min, ws.y_min - WORKSPACE.y_min, ws.z_min - WORKSPACE.z_min, 0.0]
    )
    return np.asarray(action, dtype=np.float64) + shift


def refuse_unreachable(name: str, pose: np.ndarray, ws: Workspace) -> None:
    """A pose outside the workspace or outside the arm's reach ring around the base is a TvfError."""
    x, y, z = (float(v) for v in pose[:3])
    if not bool(ws.contains_xy(pose[:2])) or not ws.z_min <= z <= ws.z_max:
        raise TvfError(
            f"refused: the {name} at (x, y, z) = ({x:.3f}, {y:.3f}, {z:.3f}) m lies outside the workspace "
            f"x [{ws.x_min}, {ws.x_max}), y [{ws.y_min}, {ws.y_max}), z [{ws.z_min}, {ws.z_max}]; "
            "no decision was written"
        )
    r = math.hypot(x, y)
    if not REACH[0] <= r <= REACH[1]:
        raise TvfError(
            f"refused: the {name} at (x, y) = ({x:.3f}, {y:.3f}) m is {r:.3f} m from the robot base, outside "
            f"the arm's reach {REACH[0]}-{REACH[1]} m (tvf.geometry.REACH); no decision was written"
        )


def pose_matrix(pose: np.ndarray) -> np.ndarray:
    """``(x, y, z, yaw)`` -> the 4 x 4 ``T_base_tool``: translation (x, y, z), rotation yaw about z."""
    x, y, z, yaw = (float(v) for v in pose)
    c, s = math.cos(yaw), math.sin(yaw)
    T = np.array([[c, -s, 0.0, x], [s, c, 0.0, y], [0.0, 0.0, 1.0, z], [0.0, 0.0, 0.0, 1.0]])
    return T + 0.0  # -0.0 -> 0.0 in the JSON


def pose_record(pose: np.ndarray, pixel: tuple[int, int]) -> dict:
    x, y, z, yaw = (float(v) for v in pose)
    return {
        "x": x,
        "y": y,
        "z": z,
        "yaw": yaw,
        "T_base_tool": pose_matrix(pose).tolist(),
        "pixel": list(pixel),
    }


def image_record(image) -> dict:
    record = {"path": str(image.source), "views": image.n_views, "coverage": round(image.coverage, 6),
              "hole_fill": image.hole_fill}  # fmt: skip
    if image.levelling:
        record["levelling"] = list(image.levelling)
    return record


def decision_record(decision, poses: np.ndarray, method: str, scene, goal, ws: Workspace) -> dict:
    """decision.json: pick and place in the base frame (x, y, z, yaw and 4 x 4), pixels, rotation bin."""
    turn = math.degrees(float(poses[1, 3] - poses[0, 3]))
    return {
        "method": method,
        "pick": pose_record(poses[0], decision.pick_pixel),
        "place": pose_record(poses[1], decision.place_pixel),
        "rotation_bin": decision.rotation_bin,
        "n_rotations": decision.n_rotations,
        "turn_deg": round(turn, 6),
        "convention": POSE_CONVENTION,
        "scene": image_record(scene),
        "goal": image_record(goal),
        "workspace": ws.as_dict(),
    }


def picture_lines(record: dict) -> list[str]:
    """The text over decision.png: where the images came from, the decision in pixels and metres."""
    pick, place, scene = record["pick"], record["place"], record["scene"]
    views = f"{scene['views']} view{'s' if scene['views'] != 1 else ''}"
    measured = f"{views}, {scene['coverage']:.1%} of pixels measured" if scene["views"] else "RGB-H"
    (pr, pc), (qr, qc) = pick["pixel"], place["pixel"]
    at = {k: f"({p['x']:.3f}, {p['y']:.3f}, {p['z']:.3f})" for k, p in (("pick", pick), ("place", place))}
    return [
        f"tvf plan · {record['method']} · {scene['path']} ({measured})",
        f"pick ({pr}, {pc}) -> place ({qr}, {qc}) px = {at['pick']} -> {at['place']} m in the robot base "
        f"frame, turn {record['turn_deg']:+.0f}° (bin {record['rotation_bin']} of {record['n_rotations']})",
    ]


@dataclass(frozen=True)
class PlanCmd:
    """Plan the next pick and place from calibrated RGB-D views (a real rig's files, docs/real-robot.md):
    writes decision.json (pick and place in the robot base frame: x, y, z, yaw and 4 x 4), decision.png
    and the fused images scene.npz and goal.npz. Refuses an action outside the workspace or the reach.
    Example: tvf plan --views rig/scene --goal rig/goal --out plan"""

    views: Path
    """The scene now: a folder of views (NAME.yaml + NAME.color.png + NAME.depth.png per camera) or an
    .npz RGB-H image (arrays color, height)."""
    goal: Path
    """The finished structure: a folder of views, or an .npz RGB-H image (e.g. `tvf render`'s goal.npz)."""
    out: Path
    """Output directory."""
    method: str = "tvf-large"
    """gctn | tvf-small | tvf-large."""
    gctn: Path | None = None
    """GCTN run folder, .pt or .safetensors file; default: the shipped weights."""
    vf: Path | None = None
    """VF run folder, .pt or .safetensors file (TVF methods); default: the shipped weights."""
    workspace: Path | None = None
    """Workspace file (bounds in the base frame, pixel size; docs/real-robot.md); default:
    VIEWS/workspace.yaml when the views are a folder that has one, else today's workspace."""
    turns: int | None = None
    """Average the GCTN's maps over 1, 2 or 4 quarter turns of the scene, or 8 (and their mirror images);
    default: the method's."""
    goal_mask: bool | None = None
    """True / False: mask the GCTN's maps by the height difference to the goal or not (False: the
    paper's; docs/planner.md); default: the method's."""
    mask_places: str | None = None
    """With the goal mask: gap | centred | bottom-up | ordered | layered | cells, the places it keeps
    (docs/planner.md); default: the method's (cells for every learned method)."""
    centred_share: float | None = None
    """With --mask-places centred, ordered, layered or cells: how near a region's middle a place lies (a share
    of the best-filled footprint; default 0.9, docs/planner.md)."""
    refine_yaw: bool | None = None
    """True / False: set the place's turn to the block yaws read from the two height maps where both
    readings are clear, or keep the GCTN's bin (False: the paper's; docs/planner.md); default: the
    method's."""
    centre_picks: bool | None = None
    """True / False: move the GCTN's picks to the centres of the block faces under them, or keep its pick
    pixels (False: the paper's; docs/planner.md); default: the method's (True for every learned method)."""
    tie_band: float | None = None
    """TVF: root actions scoring within TIE_BAND of the best are ties, decided by the GCTN's order
    (default: the method's, tvf-small 0.002, tvf-large 0; 0: the paper's; 0.001 is about a fifteenth of
    a misplaced block; docs/planner.md)."""
    foresight: Literal["vf", "rigid", "rigid-falls"] | None = None
    """TVF: what draws the search's imagined images: vf (the VF, the default) | rigid (no network: the
    picked block moved as a rigid body on the height map; docs/planner.md) | rigid-falls (rigid, and a
    block whose centre is not over its support tips off it)."""
    hole_fill: Literal["auto", "nearest", "background"] = "auto"
    """auto | nearest | background: how pixels no camera measured are filled. nearest: the nearest
    measured pixel's values; background: the lowest surface on the hole's rim (what a camera's occlusion
    shadow hides); auto: background with one camera, nearest with more (as the simulator)."""
    level_table: bool = False
    """Before fusing, level each camera on the table it sees: a plane fit of the table points corrects
    the tilt and height of a slightly wrong T_base_camera (a degree, a centimetre; not its turn about the
    vertical nor its shift along the table). decision.json records each camera's correction, so a large
    one tells you to calibrate again (docs/real-robot.md)."""
    device: str = "auto"
    """auto | cpu | cuda: where the models run."""

    def resolve_workspace(self) -> Workspace:
        from tvf.views import folder_workspace, read_workspace

        if self.workspace is not None:
            return read_workspace(self.workspace)
        return folder_workspace(self.views) if self.views.is_dir() else WORKSPACE

    def check_goal_workspace(self, ws: Workspace) -> None:
        """Goal views recorded with another workspace file than the scene's would be fused on the wrong
        grid: refused, unless --workspace names the one to use for both."""
        from tvf.views import folder_workspace

        if self.workspace is None and self.goal.is_dir() and folder_workspace(self.goal) != ws:
            raise TvfError(
                f"{self.goal} was recorded with another workspace (its workspace file) than {self.views}; "
                "record both with one workspace file, or pass --workspace FILE to fuse both on it"
            )

    def run(self) -> None:
        from tvf.api import load_planner
        from tvf.evaluate.recording import RecordedStep
        from tvf.io import atomic_write_bytes, atomic_write_json
        from tvf.views import load_rgbh, rgbh_bytes
        from tvf.viz.images import save_png
        from tvf.viz.recorded import decision_picture

        out = check_output_dir(self.out)
        ws = self.resolve_workspace()
        check_grid(ws, str(self.workspace or self.views))
        self.check_goal_workspace(ws)
        scene = load_rgbh(self.views, ws, "--views", self.hole_fill, self.level_table)
        goal = load_rgbh(self.goal, ws, "--goal", self.hole_fill, self.level_table)
        search = {} if self.tie_band is None else {"tie_band": self.tie_band}
        planner = load_planner(self.method, gctn=_path(self.gctn), vf=_path(self.vf), device=self.device,
                               keep_images=True, turns=self.turns, goal_mask=self.goal_mask,
                               mask_places=self.mask_places, centred_share=self.centred_share,
                               refine_yaw=self.refine_yaw, centre_picks=self.centre_picks,
                               foresight=self.foresight, **search)  # fmt: skip
        decision = planner.next_action(scene.color, scene.height, goal.color, goal.height)
        poses = to_base_frame(decision.as_array(), ws)
        for name, pose in (("pick", poses[0]), ("place", poses[1])):
            refuse_unreachable(name, pose, ws)
        record = decision_record(decision, poses, self.method, scene, goal, ws)
        obs = {"color": scene.color, "height": scene.height}
        step = RecordedStep(
            obs, {"color": goal.color, "height": goal.height}, decision.plan, decision.as_array()
        )
        for name, image in (("scene", scene), ("goal", goal)):
            atomic_write_bytes(out / f"{name}.npz", rgbh_bytes(image.color, image.height))
        save_png(out / "decision.png", decision_picture(step, picture_lines(record)))
        atomic_write_json(out / "decision.json", record)
        pick, place = record["pick"], record["place"]
        print(
            f"pick ({pick['x']:.3f}, {pick['y']:.3f}, {pick['z']:.3f}) m -> place ({place['x']:.3f}, "
            f"{place['y']:.3f}, {place['z']:.3f}) m, turn {record['turn_deg']:+.0f}°: wrote decision.json, "
            f"decision.png to {out}"
        )


def _path(p: Path | None) -> str | None:
    return str(p) if p else None
