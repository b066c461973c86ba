"""A Franka Panda with a suction cup at its flange, and the pick-and-place primitive.

The arm is ``pybullet_data``'s Panda with the two fingers removed (7 DoF) and a rigid suction cylinder
fixed to the hand; the tip link's frame sits at the cup's face, so IK targets the tip directly.
Suction is a fixed constraint made when the tip touches a block and removed on release, as a real cup.

Every loop here has a step budget: nothing depends on wall-clock time or machine speed.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as p
import pybullet_data

ARM_JOINTS = 7
TIP_LINK = 9
"""Link index of the suction tip (joints 0-6 arm, 7 flange, 8 hand, 9 tip)."""
HOME = (0.0, -0.5, 0.0, -2.3, 0.0, 1.8, 0.785)
CUP_LENGTH = 0.07
ASSET_VERSION = "2"
"""Bump when the generated URDF changes, so stale cached copies are not reused."""
CUP_RADIUS = 0.01


@dataclass(frozen=True)
class MotionConfig:
    """Speeds, tolerances and budgets of the primitive (sim steps, never seconds of wall time)."""

    travel_height: float = 0.20
    """Tip height (m) for moves between pick and place; clears a 3-layer structure plus a held block."""
    approach: float = 0.02
    """The slow descent starts this far (m) above the expected contact."""
    overshoot: float = 0.03
    """The descent gives up this far (m) below the expected contact."""
    fast_speed: float = 0.8
    """Tip speed (m/s) for moves at travel height."""
    approach_speed: float = 0.3
    """Tip speed (m/s) for the vertical moves to the start of a descent (faster ones overshoot)."""
    slow_speed: float = 0.05
    """Tip speed (m/s) of the contact-seeking descents."""
    position_gain: float = 0.3
    """Joint position-control gain (PyBullet POSITION_CONTROL)."""
    ik_every: int = 4
    """Physics steps between IK updates along a path."""
    ik_iterations: int = 50
    settle_tolerance: float = 5e-4
    """Precise moves (the points above pick and place) wait until the tip is this close (m)."""
    via_tolerance: float = 0.01
    """Other moves are done once the tip is this close (m)."""
    settle_steps: int = 120
    release_steps: int = 36
    contact_distance: float = 5e-4
    budget_factor: float = 2.0
    """A move may take this many times its nominal number of steps (plus settle_steps)."""


def panda_suction_urdf() -> Path:
    """Write (once, atomically) the finger-less Panda with a suction tip and return its path."""
    data = Path(pybullet_data.getDataPath()) / "franka_panda"
    source = (data / "panda.urdf").read_text()
    key = hashlib.sha1((source + ASSET_VERSION + str(CUP_LENGTH) + str(CUP_RADIUS)).encode()).hexdigest()[:12]
    out = Path(tempfile.gettempdir()) / f"tvf-assets-{key}" / "panda_suction.urdf"
    if out.exists():
        return out
    root = ET.fromstring(source)
    drop_links = {"panda_leftfinger", "panda_rightfinger", "panda_grasptarget"}
    for el in list(root):
        if el.tag == "link" and el.get("name") in drop_links:
            root.remove(el)
        if el.tag == "joint" and el.find("child").get("link") in drop_links:
            root.remove(el)
    for mesh in root.iter("mesh"):
        name = mesh.get("filename", "").replace("package://", "")
        mesh.set("filename", str(data / name))
    root.append(_suction_link())
    root.append(_suction_joint())
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, suffix=".urdf")
    with os.fdopen(fd, "w") as f:
        f.write(ET.tostring(root, encoding="unicode"))
    os.replace(tmp, out)
    return out


def _suction_link() -> ET.Element:
    link = ET.Element("link", name="suction_tip")
    inertial = ET.SubElement(link, "inertial")
    # Inertial frame == link frame, so constraint frames (given in the inertial frame) are tip frames.
    ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(inertial, "mass", value="0.05")
    ET.SubElement(inertial, "inertia", ixx="1e-4", ixy="0", ixz="0", iyy="1e-4", iyz="0", izz="1e-4")
    for tag in ("visual", "collision"):
        el = ET.SubElement(link, tag)
        ET.SubElement(el, "origin", xyz=f"0 0 {-CUP_LENGTH / 2}", rpy="0 0 0")
        geom = ET.SubElement(el, "geometry")
        ET.SubElement(geom, "cylinder", radius=str(CUP_RADIUS), length=str(CUP_LENGTH))
        if tag == "visual":
            mat = ET.SubElement(el, "material", name="suction_grey")
            ET.SubElement(mat, "color", rgba="0.3 0.3 0.3 1")
    return link


def _suction_joint() -> ET.Element:
    joint = ET.Element("joint", name="suction_joint", type="fixed")
    ET.SubElement(joint, "parent", link="panda_hand")
    ET.SubElement(joint, "child", link="suction_tip")
    # The hand mesh ends 6.6 cm below its frame; the cup's face is CUP_LENGTH further down.
    ET.SubElement(joint, "origin", xyz=f"0 0 {0.066 + CUP_LENGTH}", rpy="0 0 0")
    return joint


@dataclass
class PrimitiveResult:
    """What one pick-and-place did."""

    grasped: bool
    released: bool
    reason: str
    """'ok', or why the primitive failed: no_pick_contact, nothing_to_grasp, motion_budget, ..."""
    steps: int


class SuctionArm:
    """The Panda arm, its suction cup and the pick-and-place primitive, in one PyBullet client."""

    def __init__(self, client: int, config: MotionConfig | None = None) -> None:
        self.client = client
        self.config = config or MotionConfig()
        self.body = p.loadURDF(
            str(panda_suction_urdf()), [0, 0, 0], useFixedBase=True, physicsClientId=client
        )
        info = [p.getJointInfo(self.body, j, physicsClientId=client) for j in range(ARM_JOINTS)]
        self.lower = np.array([i[8] for i in info])
        self.upper = np.array([i[9] for i in info])
        self.forces = np.array([i[10] for i in info])
        self.held: int | None = None
        self._constraint: int | None = None
        self.steps = 0
        self.reset()
        self._nominal_offset = self._tool_yaw() - math.atan2(*self.tip_position()[1::-1])

    # ---------------------------------------------------------------- state
    def reset(self) -> None:
        self.release()
        self.set_joints(HOME)
        self._command(np.array(HOME))

    def set_joints(self, q) -> None:
        for j, v in enumerate(q):
            p.resetJointState(self.body, j, v, 0.0, physicsClientId=self.client)

    def joints(self) -> np.ndarray:
        states = p.getJointStates(self.body, range(ARM_JOINTS), physicsClientId=self.client)
        return np.array([s[0] for s in states])

    def tip_pose(self) -> tuple[np.ndarray, np.ndarray]:
        state = p.getLinkState(
            self.body, TIP_LINK, computeForwardKinematics=True, physicsClientId=self.client
        )
        return np.array(state[4]), np.array(state[5])

    def tip_position(self) -> np.ndarray:
        return self.tip_pose()[0]

    def _tool_yaw(self) -> float:
        quat = self.tip_pose()[1]
        m = np.array(p.getMatrixFromQuaternion(quat)).reshape(3, 3)
        return math.atan2(m[1, 0], m[0, 0])

    def nominal_tool_yaw(self, xy: np.ndarray) -> float:
        """The tool yaw that keeps the wrist near the middle of its range at ``xy``."""
        return math.atan2(xy[1], xy[0]) + self._nominal_offset

    # ---------------------------------------------------------------- low-level motion
    def _command(self, q: np.ndarray) -> None:
        p.setJointMotorControlArray(
            self.body,
            list(range(ARM_JOINTS)),
            p.POSITION_CONTROL,
            targetPositions=list(q),
            forces=list(self.forces),
            positionGains=[self.config.position_gain] * ARM_JOINTS,
            physicsClientId=self.client,
        )

    def _ik(self, position: np.ndarray, yaw: float) -> np.ndarray:
        orn = p.getQuaternionFromEuler([math.pi, 0.0, yaw])
        rest = list(HOME)
        rest[0] = math.atan2(position[1], position[0])
        q = p.calculateInverseKinematics(
            self.body,
            TIP_LINK,
            list(position),
            orn,
            lowerLimits=list(self.lower),
            upperLimits=list(self.upper),
            jointRanges=list(self.upper - self.lower),
            restPoses=rest,
            maxNumIterations=self.config.ik_iterations,
            residualThreshold=1e-4,
            physicsClientId=self.client,
        )
        return np.clip(np.array(q[:ARM_JOINTS]), self.lower, self.upper)

    def _step(self) -> None:
        p.stepSimulation(physicsClientId=self.client)
        self.steps += 1

    def move_line(
        self, target: np.ndarray, yaw: float, speed: float, until=None, precise: bool = False
    ) -> str:
        """Move the tip along a straight line to ``target`` with tool yaw ``yaw``.

        ``until`` is an optional predicate checked after every physics step; the move stops when
        it holds. A ``precise`` move waits for the tip to settle within ``settle_tolerance``, others
        within ``via_tolerance``. Returns 'ok', 'stopped' (the predicate fired) or 'motion_budget'.
        """
        cfg = self.config
        tolerance = cfg.settle_tolerance if precise else cfg.via_tolerance
        hz = self._hz()
        start = self.tip_position()
        start_yaw = self._tool_yaw()
        yaw_delta = math.remainder(yaw - start_yaw, 2 * math.pi)
        distance = float(np.linalg.norm(target - start))
        n = max(1, int(math.ceil(max(distance / speed, abs(yaw_delta) / 2.0) * hz)))
        budget = int(cfg.budget_factor * n) + cfg.settle_steps
        for i in range(1, n + 1):
            if i % cfg.ik_every == 1 or i == n or cfg.ik_every == 1:
                s = i / n
                self._command(self._ik(start + s * (target - start), start_yaw + s * yaw_delta))
            self._step()
            budget -= 1
            if until is not None and until():
                return "stopped"
        aim = np.array(target, dtype=float)
        while budget > 0:
            error = target - self.tip_position()
            if np.linalg.norm(error) < tolerance:
                return "ok"
            if until is not None and until():
                return "stopped"
            # IK with null-space terms leaves a residual of a few mm far from the base: aim past the
            # target by the accumulated error (an integral term) so the tip itself converges.
            aim = target + np.clip(aim - target + 0.5 * error, -0.02, 0.02)
            self._command(self._ik(aim, yaw))
            for _ in range(cfg.ik_every):
                self._step()
                budget -= 1
        return "ok" if np.linalg.norm(self.tip_position() - target) < 5 * tolerance else "motion_budget"

    def _hz(self) -> float:
        return 1.0 / p.getPhysicsEngineParameters(physicsClientId=self.client)["fixedTimeStep"]

    # ---------------------------------------------------------------- suction
    def _tip_contact(self, blocks: set[int]) -> int | None:
        """The body the tip touches (a block id, or -1 for anything else), or None."""
        for pt in p.getContactPoints(bodyA=self.body, linkIndexA=TIP_LINK, physicsClientId=self.client):
            if pt[8] <= self.config.contact_distance and pt[2] != self.body:
                return pt[2] if pt[2] in blocks else -1
        return None

    def _held_contact(self) -> bool:
        """Whether the held block touches anything but the robot."""
        if self.held is None:
            return False
        for pt in p.getContactPoints(bodyA=self.held, physicsClientId=self.client):
            if pt[8] <= self.config.contact_distance and pt[2] != self.body:
                return True
        return False

    def grasp(self, block: int) -> None:
        # Constraint frames are expressed in the link's inertial frame (state[0], state[1]).
        state = p.getLinkState(
            self.body, TIP_LINK, computeForwardKinematics=True, physicsClientId=self.client
        )
        tip_pos, tip_orn = state[0], state[1]
        pos, orn = p.getBasePositionAndOrientation(block, physicsClientId=self.client)
        inv_pos, inv_orn = p.invertTransform(tip_pos, tip_orn)
        rel_pos, rel_orn = p.multiplyTransforms(inv_pos, inv_orn, pos, orn)
        self._constraint = p.createConstraint(
            self.body, TIP_LINK, block, -1, p.JOINT_FIXED, [0, 0, 0], rel_pos, [0, 0, 0],
            parentFrameOrientation=rel_orn, physicsClientId=self.client,
        )  # fmt: skip
        p.changeConstraint(self._constraint, maxForce=20, physicsClientId=self.client)
        p.setCollisionFilterPair(self.body, block, TIP_LINK, -1, 0, physicsClientId=self.client)
        self.held = block

    def release(self) -> None:
        if self._constraint is not None:
            p.removeConstraint(self._constraint, physicsClientId=self.client)
        self._constraint = None

    def _restore_collisions(self) -> None:
        if self.held is not None:
            p.setCollisionFilterPair(self.body, self.held, TIP_LINK, -1, 1, physicsClientId=self.client)
        self.held = None

    # ---------------------------------------------------------------- the primitive
    def pick_and_place(self, pick: np.ndarray, place: np.ndarray, blocks: set[int]) -> PrimitiveResult:
        """Pick at ``pick`` = (x, y, z, yaw) with the suction tip and place so the tool ends at ``place``.

        The held block moves rigidly with the tool: its yaw changes by ``place[3] - pick[3]``.
        """
        cfg = self.config
        self.steps = 0
        delta = math.remainder(float(place[3] - pick[3]), 2 * math.pi)
        yaw_pick = self.nominal_tool_yaw(pick[:2]) - delta / 2
        yaw_place = yaw_pick + delta
        pick_xyz = np.asarray(pick[:3], dtype=float)
        place_xyz = np.asarray(place[:3], dtype=float)
        touched: list[int | None] = [None]

        def tip_touch() -> bool:
            touched[0] = self._tip_contact(blocks)
            return touched[0] is not None

        def up(xyz: np.ndarray) -> np.ndarray:
            return np.array([xyz[0], xyz[1], max(cfg.travel_height, xyz[2] + cfg.approach)])

        # --- pick
        for target, precise in ((up(self.tip_position()), False), (up(pick_xyz), True)):
            if self.move_line(target, yaw_pick, cfg.fast_speed, precise=precise) == "motion_budget":
                return PrimitiveResult(False, False, "motion_budget", self.steps)
        above = pick_xyz + [0, 0, cfg.approach]
        if (
            self.move_line(above, yaw_pick, cfg.approach_speed, until=tip_touch, precise=True)
            == "motion_budget"
        ):
            return PrimitiveResult(False, False, "motion_budget", self.steps)
        if touched[0] is None:
            self.move_line(pick_xyz - [0, 0, cfg.overshoot], yaw_pick, cfg.slow_speed, until=tip_touch)
        grasped = touched[0] is not None and touched[0] >= 0
        if grasped:
            self.grasp(int(touched[0]))
        reason = "ok" if grasped else ("no_pick_contact" if touched[0] is None else "nothing_to_grasp")
        hold_pos = self.tip_position()
        self._hold_still(4)
        # The cup grasped where it touched, which may differ a little from the commanded pick point:
        # shift the place so the commanded point of the block (not the touched one) lands on target.
        place_xyz = place_xyz.copy()
        place_xyz[:2] += _rotate2(hold_pos[:2] - pick_xyz[:2], delta)
        # --- carry
        for target, precise in ((up(hold_pos), False), (up(place_xyz), True)):
            if self.move_line(target, yaw_place, cfg.fast_speed, precise=precise) == "motion_budget":
                self.release()
                self._restore_collisions()
                return PrimitiveResult(grasped, False, "motion_budget", self.steps)
        # --- place
        above = place_xyz + [0, 0, cfg.approach]
        self.move_line(above, yaw_place, cfg.approach_speed, until=self._held_contact, precise=True)
        if not self._held_contact():
            self.move_line(
                place_xyz - [0, 0, cfg.overshoot], yaw_place, cfg.slow_speed, until=self._held_contact
            )
        released = self.held is not None
        self.release()
        self._hold_still(cfg.release_steps)
        retreat = self.tip_position() + [0, 0, 0.05]
        self.move_line(retreat, yaw_place, cfg.slow_speed * 2)
        self._restore_collisions()
        self.move_line(up(retreat), yaw_place, cfg.fast_speed)
        return PrimitiveResult(grasped, released and grasped, reason, self.steps)

    def _hold_still(self, steps: int) -> None:
        """Command the current joint angles and step ``steps`` times."""
        self._command(self.joints())
        for _ in range(steps):
            self._step()


def _rotate2(v: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])
