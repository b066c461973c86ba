"""The PyBullet tabletop: table, a task's base and blocks, the suction arm and the cameras.

One ``World`` owns one PyBullet client (DIRECT by default, GUI on request). ``build`` lays out a new
scene for a task from an explicit ``numpy.random.Generator``; nothing here touches a global RNG.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import pybullet as p

from tvf.errors import TvfError
from tvf.fusion import PinholeCamera, View, fuse
from tvf.geometry import EDGE_MARGIN, REACH, WORKSPACE, Workspace, rotate_xy
from tvf.sim.camera import ObservationConfig, Rig, render_views
from tvf.sim.robot import MotionConfig, SuctionArm
from tvf.tasks import BLOCK_RADIUS, BLOCK_SIZE, CELL_RADIUS, CELL_SIZE, CELL_THICKNESS, Task

BLOCK_COLOUR = (255 / 255, 87 / 255, 89 / 255, 1.0)
TABLE_COLOUR = (0.2, 0.2, 0.2, 1.0)
TABLE_HALF_SIZE = 0.4
HIDDEN = (0.0, 0.0, 50.0)
"""Where the arm's base goes while the cameras render: above and behind every camera."""
BLOCK_MASS = 0.01


class SceneError(TvfError):
    """A scene could not be laid out (too little free space)."""


@dataclass(frozen=True)
class SceneConfig:
    """Where things may be placed when a scene is sampled."""

    edge_margin: float = EDGE_MARGIN
    """Every block, base cell and target keeps this far (m) inside the workspace edges."""
    reach: tuple[float, float] = REACH
    """Everything lies within this ring (m) around the robot base, where the Panda reaches the table."""
    clearance: float = 0.015
    """Gap (m) kept between the circumscribed circles of loose blocks and base cells."""
    tries: int = 2000
    """Rejection-sampling budget per object; beyond it the scene fails with a SceneError."""


@dataclass(frozen=True)
class SimConfig:
    hz: int = 240
    solver_iterations: int = 50
    settle_steps: int = 480
    """Budget (physics steps) for blocks to come to rest after an action."""
    gui: bool = False
    scene: SceneConfig = field(default_factory=SceneConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    observation: ObservationConfig = field(default_factory=ObservationConfig)


@dataclass(frozen=True)
class Layout:
    """A sampled scene: base pose and block poses (x, y, yaw)."""

    base_xy: tuple[float, float]
    base_yaw: float
    blocks: tuple[tuple[float, float, float], ...]


class World:
    """A PyBullet world holding one scene at a time."""

    def __init__(self, config: SimConfig | None = None, workspace: Workspace = WORKSPACE) -> None:
        self.config = config or SimConfig()
        self.workspace = workspace
        self.client = p.connect(p.GUI if self.config.gui else p.DIRECT)
        if not p.isNumpyEnabled():
            raise RuntimeError("this pybullet build has NumPy disabled; reinstall pybullet from the wheel")
        self.task: Task | None = None
        self.layout: Layout | None = None
        self.cells: list[int] = []
        self.blocks: list[int] = []
        self._setup()

    def _setup(self) -> None:
        """Physics settings, the table and the arm, in an empty simulation."""
        p.setGravity(0, 0, -9.8, physicsClientId=self.client)
        p.setPhysicsEngineParameter(
            fixedTimeStep=1.0 / self.config.hz,
            numSolverIterations=self.config.solver_iterations,
            physicsClientId=self.client,
        )
        self._block_shape = self._box_shapes((BLOCK_SIZE / 2,) * 3, BLOCK_COLOUR)
        self.table = self._make_table()
        self.arm = SuctionArm(self.client, self.config.motion)

    def close(self) -> None:
        if p.isConnected(self.client):
            p.disconnect(self.client)

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---------------------------------------------------------------- bodies
    def _box_shapes(self, half: tuple[float, float, float], rgba) -> tuple[int, int]:
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=self.client)
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=rgba, physicsClientId=self.client)
        return col, vis

    def _make_table(self) -> int:
        # An infinite collision plane, but a visible table top only a little larger than the workspace:
        # TinyRenderer's cost grows with the screen area that triangles cover.
        col = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=self.client)
        cx, cy = self.workspace.center
        vis = p.createVisualShape(
            p.GEOM_BOX, halfExtents=[TABLE_HALF_SIZE, TABLE_HALF_SIZE, 0.0005],
            visualFramePosition=[cx, cy, -0.0005],
            rgbaColor=TABLE_COLOUR, physicsClientId=self.client,
        )  # fmt: skip
        body = p.createMultiBody(0, col, vis, [0, 0, 0], physicsClientId=self.client)
        p.changeDynamics(body, -1, lateralFriction=1.0, physicsClientId=self.client)
        return body

    def _add_block(self, x: float, y: float, z: float, yaw: float) -> int:
        col, vis = self._block_shape
        orn = p.getQuaternionFromEuler([0, 0, yaw])
        body = p.createMultiBody(BLOCK_MASS, col, vis, [x, y, z], orn, physicsClientId=self.client)
        p.changeDynamics(
            body, -1, lateralFriction=1.0, rollingFriction=1e-4, spinningFriction=1e-4,
            physicsClientId=self.client,
        )  # fmt: skip
        return body

    def _add_cell(self, x: float, y: float, yaw: float, colour) -> int:
        col, vis = self._box_shapes((CELL_SIZE / 2, CELL_SIZE / 2, CELL_THICKNESS / 2), (*colour, 1.0))
        orn = p.getQuaternionFromEuler([0, 0, yaw])
        body = p.createMultiBody(0, col, vis, [x, y, CELL_THICKNESS / 2], orn, physicsClientId=self.client)
        p.changeDynamics(body, -1, lateralFriction=1.0, physicsClientId=self.client)
        return body

    def clear(self) -> None:
        """Empty the simulation and rebuild the table and arm.

        A full reset (rather than removing the last scene's bodies) makes every episode independent of
        what ran before in this process: body ids, contact order and solver state start afresh, so the
        same seed gives bit-identical results in a fresh or a reused world (about 0.1 s).
        """
        p.resetSimulation(physicsClientId=self.client)
        self.blocks, self.cells = [], []
        self._setup()

    # ---------------------------------------------------------------- scenes
    def build(self, task: Task, rng: np.random.Generator) -> Layout:
        """Clear the world and lay out ``task``'s base and loose blocks at random, collision-free."""
        layout = sample_layout(task, rng, self.config.scene, self.workspace)
        self.load(task, layout)
        return layout

    def load(self, task: Task, layout: Layout) -> None:
        """Clear the world and create the bodies of ``layout``."""
        self.clear()
        self.task, self.layout = task, layout
        centres = layout_cell_centres(task, layout)
        for cell, (x, y) in zip(task.cells, centres, strict=True):
            self.cells.append(self._add_cell(x, y, layout.base_yaw, cell.colour))
        for x, y, yaw in layout.blocks:
            self.blocks.append(self._add_block(x, y, BLOCK_SIZE / 2, yaw))
        self.settle()

    def target_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """World target centres ``(n, 3)`` and yaws ``(n,)`` of the current scene."""
        assert self.task is not None and self.layout is not None
        offsets = self.task.target_offsets()
        xy = rotate_xy(offsets[:, :2], self.layout.base_yaw) + np.asarray(self.layout.base_xy)
        pos = np.concatenate([xy, offsets[:, 2:]], axis=1)
        return pos, np.full(len(pos), self.layout.base_yaw)

    def block_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """Block centres ``(n, 3)`` and yaws ``(n,)``."""
        pos, yaw = [], []
        for b in self.blocks:
            xyz, quat = p.getBasePositionAndOrientation(b, physicsClientId=self.client)
            pos.append(xyz)
            yaw.append(p.getEulerFromQuaternion(quat)[2])
        return np.asarray(pos, dtype=np.float64).reshape(-1, 3), np.asarray(yaw, dtype=np.float64)

    def set_block_poses(self, pos: np.ndarray, yaw: np.ndarray) -> None:
        for b, xyz, a in zip(self.blocks, pos, yaw, strict=True):
            orn = p.getQuaternionFromEuler([0, 0, float(a)])
            p.resetBasePositionAndOrientation(b, list(map(float, xyz)), orn, physicsClientId=self.client)
            p.resetBaseVelocity(b, [0, 0, 0], [0, 0, 0], physicsClientId=self.client)

    # ---------------------------------------------------------------- physics
    def settle(self, max_steps: int | None = None, speed: float = 5e-3) -> bool:
        """Step until every block moves slower than ``speed`` m/s; False if the budget ran out."""
        budget = self.config.settle_steps if max_steps is None else max_steps
        for i in range(budget):
            p.stepSimulation(physicsClientId=self.client)
            if i % 8 == 7 and self._blocks_still(speed):
                return True
        return self._blocks_still(speed)

    def _blocks_still(self, speed: float) -> bool:
        for b in self.blocks:
            lin, ang = p.getBaseVelocity(b, physicsClientId=self.client)
            if np.linalg.norm(lin) > speed or np.linalg.norm(ang) > 20 * speed:
                return False
        return True

    def save_state(self) -> int:
        return p.saveState(physicsClientId=self.client)

    def restore_state(self, state: int, remove: bool = True) -> None:
        p.restoreState(stateId=state, physicsClientId=self.client)
        if remove:
            self.forget_state(state)

    def forget_state(self, state: int) -> None:
        """Free a state of :meth:`save_state` that will not be restored."""
        p.removeState(state, physicsClientId=self.client)

    # ---------------------------------------------------------------- sensing
    def views(self, rig: Rig | None = None) -> tuple[list[View], tuple[PinholeCamera, ...]]:
        """The raw RGB-D views of the observation's cameras (colour uint8, depth float32 metres along the
        optical axis) and the cameras as calibrated intrinsics + poses (what a real rig would record);
        ``rig`` renders another rig's cameras (:data:`tvf.sim.camera.RIGS`; None: the observation's).

        The arm is lifted out of every camera's view for the render (no physics step happens
        meanwhile), which is cheaper than rendering it parked and never occludes the workspace.
        """
        p.resetBasePositionAndOrientation(self.arm.body, HIDDEN, [0, 0, 0, 1], physicsClientId=self.client)
        cfg = self.config.observation if rig is None else replace(self.config.observation, rig=rig)
        try:
            return render_views(self.client, cfg), cfg.pinholes()
        finally:
            p.resetBasePositionAndOrientation(
                self.arm.body, [0, 0, 0], [0, 0, 0, 1], physicsClientId=self.client
            )

    def fuse(self, views: list[View], cameras: tuple[PinholeCamera, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Views fused into the top-down image (colour uint8 HxWx3, height float32 HxW), holes filled as
        the observation config says."""
        return fuse(views, cameras, self.workspace, self.config.observation.fill_holes)

    def observe(self) -> tuple[np.ndarray, np.ndarray]:
        """The fused top-down image of :meth:`views`."""
        return self.fuse(*self.views())

    def goal_views(self, rig: Rig | None = None) -> tuple[list[View], tuple[PinholeCamera, ...]]:
        """:meth:`views` (of ``rig``'s cameras) of the finished structure: blocks settled on their targets,
        scene restored after."""
        state = self.save_state()
        try:
            pos, yaw = self.target_poses()
            order = np.argsort(pos[:, 2], kind="stable")
            self.set_block_poses(pos[order] + [0, 0, 1e-4], yaw[order])
            self.settle(120)
            return self.views(rig)
        finally:
            self.restore_state(state)

    def goal_observation(self) -> tuple[np.ndarray, np.ndarray]:
        """The fused image of the finished structure (:meth:`goal_views`)."""
        return self.fuse(*self.goal_views())


# -------------------------------------------------------------------- layout sampling
def layout_cell_centres(task: Task, layout: Layout) -> np.ndarray:
    return rotate_xy(task.cell_offsets(), layout.base_yaw) + np.asarray(layout.base_xy)


def _inside(points: np.ndarray, radius: float, cfg: SceneConfig, ws: Workspace) -> bool:
    """Whether discs of ``radius`` around ``points (k, 2)`` lie in the workspace and the reach ring."""
    r = np.linalg.norm(points, axis=-1)
    return bool(
        ws.contains_xy(points, cfg.edge_margin + radius).all()
        and (r - radius >= cfg.reach[0]).all()
        and (r + radius <= cfg.reach[1]).all()
    )


def sample_layout(
    task: Task, rng: np.random.Generator, cfg: SceneConfig, ws: Workspace = WORKSPACE
) -> Layout:
    """Sample a collision-free layout: the base first (its true footprint, and every target inside the
    workspace and the reach too), then each block."""
    lo = np.array([ws.x_min, ws.y_min])
    hi = np.array([ws.x_max, ws.y_max])
    offsets, targets = task.cell_offsets(), task.target_offsets()[:, :2]
    for _ in range(cfg.tries):
        base_xy, base_yaw = rng.uniform(lo, hi), float(rng.uniform(-math.pi, math.pi))
        cells = rotate_xy(offsets, base_yaw) + base_xy
        if _inside(cells, CELL_RADIUS, cfg, ws) and _inside(
            rotate_xy(targets, base_yaw) + base_xy, BLOCK_RADIUS, cfg, ws
        ):
            break
    else:
        raise SceneError(
            f"task {task.name!r}: could not place its base inside the workspace in {cfg.tries} tries; "
            "the base is too large for the workspace and reach limits"
        )
    discs = [(c, CELL_RADIUS) for c in cells]
    blocks = []
    for i in range(task.n_blocks):
        xy, yaw = sample_free_pose(rng, discs, cfg, ws)
        if xy is None:
            raise SceneError(
                f"task {task.name!r}: no free space for block {i + 1} of {task.n_blocks} after "
                f"{cfg.tries} tries; use fewer blocks or a smaller base"
            )
        discs.append((xy, BLOCK_RADIUS))
        blocks.append((float(xy[0]), float(xy[1]), yaw))
    return Layout((float(base_xy[0]), float(base_xy[1])), base_yaw, tuple(blocks))


def sample_free_pose(
    rng: np.random.Generator, occupied: list[tuple[np.ndarray, float]], cfg: SceneConfig,
    ws: Workspace = WORKSPACE,
) -> tuple[np.ndarray | None, float]:  # fmt: skip
    """A block position clear of the ``occupied`` discs (centre, radius) and a random yaw."""
    lo = np.array([ws.x_min, ws.y_min])
    hi = np.array([ws.x_max, ws.y_max])
    centres = np.array([c for c, _ in occupied]).reshape(-1, 2)
    radii = np.array([r for _, r in occupied])
    for _ in range(cfg.tries):
        xy = rng.uniform(lo, hi)
        yaw = float(rng.uniform(-math.pi, math.pi))
        if not _inside(xy[None], BLOCK_RADIUS, cfg, ws):
            continue
        gaps = np.linalg.norm(centres - xy, axis=-1) - radii - BLOCK_RADIUS
        if (gaps >= cfg.clearance).all():
            return xy, yaw
    return None, 0.0
