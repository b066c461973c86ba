"""A Gymnasium environment for one rearrangement task (registered as ``tvf/<Task>-v0`` by :mod:`tvf.envs`).

``reset(seed=s)`` lays out the scene for seed ``s`` and returns the top-down image; the image of the
finished structure for that seed (made by settling the blocks on their targets in a saved copy of the
scene: independent of any expert, one render, exact targets) is in ``obs['desired_goal']`` and
``info['goal']``. ``step(action)`` runs one pick-and-place, where ``action`` is a ``(2, 4)`` array of
pick and place poses (x, y, z, yaw) in metres and radians (docs/gymnasium.md).

Sensors: ``sensor=`` (a name of :data:`tvf.sim.sensors.SENSORS` or a :class:`~tvf.sim.sensors.SensorConfig`)
chooses the camera rig and how its views are spoilt before the fusion (noise, dropout, calibration
errors); the goal image goes through the same sensor with its own draws. The default, ``ideal``, is the
simulator's perfect three cameras. ``info["coverage"]`` is the fraction of workspace pixels a camera
measured before hole filling.

Seeds: one ``numpy.random.SeedSequence(seed)`` is split into independent streams for the layout,
the oracle's order, and the oracle's and random actions' choices, so the same seed gives the same
scene, the same oracle trajectory and the same images.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import gymnasium as gym
import numpy as np

from tvf.errors import TvfError
from tvf.fusion import PinholeCamera, View, fill_holes, fuse_with_coverage
from tvf.geometry import WORKSPACE
from tvf.sim import sensors
from tvf.sim.oracle import oracle_action, random_action
from tvf.sim.sensors import SensorConfig, get_sensor
from tvf.sim.success import Progress, evaluate_structure, target_misses
from tvf.sim.world import SimConfig, World
from tvf.tasks import Task, get_task, load_tasks


class ActionError(TvfError):
    """An action that is not a (2, 4) array of numbers, is not finite or lies outside the workspace."""


class EpisodeOverError(TvfError):
    """A step after the episode terminated (gymnasium's rule: call reset() first)."""


@dataclass(frozen=True)
class EnvSnapshot:
    """The simulator's state and the episode's counters at one moment (:meth:`TvfEnv.snapshot`)."""

    state: int
    """PyBullet's in-memory saved state."""
    steps: int
    terminated: bool
    last_obs: dict | None
    coverage: dict


@dataclass(frozen=True)
class EnvConfig:
    sim: SimConfig = field(default_factory=SimConfig)
    step_slack: int = 0
    """Extra steps allowed beyond the task's horizon (one step per block) before truncation."""
    sensor: SensorConfig = field(default_factory=SensorConfig)
    """The cameras' realism (tvf.sim.sensors); its ``cameras`` sets the rig the world renders."""


def validate_action(action: np.ndarray) -> np.ndarray:
    """Return the action as a ``(2, 4)`` float array, or raise ActionError naming the problem."""
    try:
        a = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError):
        raise ActionError(
            f"an action is a (2, 4) array of numbers, pick and place (x, y, z, yaw), got {action!r:.80}"
        ) from None
    if a.shape != (2, 4):
        raise ActionError(
            f"an action is a (2, 4) array of pick and place (x, y, z, yaw), got shape {a.shape}"
        )
    if not np.isfinite(a).all():
        raise ActionError(f"action contains NaN or inf: {a.tolist()}")
    ws = WORKSPACE
    for name, pose in (("pick", a[0]), ("place", a[1])):
        if not ws.contains_xy(pose[:2]) or not (ws.z_min <= pose[2] <= ws.z_max):
            raise ActionError(
                f"{name} position {np.round(pose[:3], 4).tolist()} is outside the workspace "
                f"x [{ws.x_min}, {ws.x_max}), y [{ws.y_min}, {ws.y_max}), z [{ws.z_min}, {ws.z_max}]"
            )
    return a


def image_space() -> gym.spaces.Dict:
    """A top-down image: ``color`` uint8 (H, W, 3) and ``height`` float32 (H, W) metres above the table."""
    h, w = WORKSPACE.shape
    return gym.spaces.Dict(
        {
            "color": gym.spaces.Box(0, 255, (h, w, 3), np.uint8),
            "height": gym.spaces.Box(0.0, WORKSPACE.z_max, (h, w), np.float32),
        }
    )


def action_space() -> gym.spaces.Box:
    """Pick and place poses ``(x, y, z, yaw)`` in the workspace, metres and radians: a ``(2, 4)`` box."""
    lo = np.array([[WORKSPACE.x_min, WORKSPACE.y_min, WORKSPACE.z_min, -np.pi]] * 2)
    hi = np.array([[WORKSPACE.x_max, WORKSPACE.y_max, WORKSPACE.z_max, np.pi]] * 2)
    return gym.spaces.Box(lo, hi, dtype=np.float64)


def resolve_task(task: str | Task, task_file: str | Path | None = None) -> Task:
    """A task value, a built-in task name, or a name from ``task_file`` (tvf.tasks.load_tasks)."""
    if isinstance(task, Task):
        if task_file is not None:
            raise TvfError("pass a task name together with task_file, not a Task value")
        return task
    return load_tasks(task_file).get(task) if task_file is not None else get_task(task)


class TvfEnv(gym.Env):
    """Pick-and-place rearrangement of red blocks onto a brown base, observed top-down as RGB-H.

    Observations are ``{"color", "height", "desired_goal": {"color", "height"}}``; ``render()`` (with
    ``render_mode="rgb_array"``) returns the current top-down colour image, one frame per pick-and-place.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 1}

    def __init__(
        self,
        task: str | Task,
        config: EnvConfig | None = None,
        render_mode: str | None = None,
        gui: bool = False,
        task_file: str | Path | None = None,
        sensor: str | SensorConfig | None = None,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise TvfError(f"render_mode {render_mode!r} is not supported; use 'rgb_array' or None")
        self.task = resolve_task(task, task_file)
        self.config = config or EnvConfig()
        if gui:
            self.config = replace(self.config, sim=replace(self.config.sim, gui=True))
        if sensor is not None:
            self.config = replace(self.config, sensor=get_sensor(sensor))
        self.sensor = self.config.sensor
        obs_cfg = replace(self.config.sim.observation, rig=self.sensor.cameras)
        self.config = replace(self.config, sim=replace(self.config.sim, observation=obs_cfg))
        self.render_mode = render_mode
        self.world = World(self.config.sim)
        self.observation_space = gym.spaces.Dict({**image_space().spaces, "desired_goal": image_space()})
        self.action_space = action_space()
        self.order: tuple[tuple[int, ...], ...] = self.task.orders[0]
        self.steps = 0
        self.seed_value: int | None = None
        self.terminated = False
        """Whether the last step finished the structure; a further step needs a reset first."""
        self._oracle_rng = np.random.default_rng(0)
        self._last_obs: dict[str, np.ndarray] | None = None
        self._goal: dict[str, np.ndarray] = {}
        self.goal_views: tuple[list, tuple] = ([], ())
        """The camera views (and cameras) the goal image of this episode was fused from, as the sensor
        recorded them (with a miscalibrated sensor: the poses the rig believes)."""
        self.coverage: dict[str, float] = {}
        """The fraction of workspace pixels measured before hole filling, of the last ``obs`` and ``goal``."""

    @property
    def max_steps(self) -> int:
        return self.task.horizon + self.config.step_slack

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is None:
            seed = int(self.np_random.integers(2**31))
        self.seed_value = int(seed)
        layout_ss, order_ss, oracle_ss = np.random.SeedSequence(self.seed_value).spawn(3)
        self.world.build(self.task, np.random.default_rng(layout_ss))
        order_rng = np.random.default_rng(order_ss)
        self.order = self.task.orders[int(order_rng.integers(len(self.task.orders)))]
        self._oracle_rng = np.random.default_rng(oracle_ss)
        self.steps = 0
        self.terminated = False
        self.goal_views = self._sense(*self.world.goal_views(self.sensor.goal_rig), sensors.GOAL)
        goal_color, goal_height = self._fuse(*self.goal_views, "goal")
        self._goal = {"color": goal_color, "height": goal_height}
        obs = self._observe()
        info = self._info(self.progress())
        info["goal"] = self._goal
        return obs, info

    def _sense(
        self, views: list[View], cameras: tuple[PinholeCamera, ...], stream: int
    ) -> tuple[list[View], tuple[PinholeCamera, ...]]:  # fmt: skip
        """The rendered views as this episode's sensor records them at the current step."""
        seed = self.seed_value or 0
        return self.sensor.apply(views, cameras, seed, self.steps, stream, self.world.workspace)

    def sensed_views(self) -> tuple[list[View], tuple[PinholeCamera, ...]]:
        """The current scene's views as the sensor records them (what the observation is fused from)."""
        return self._sense(*self.world.views(), sensors.OBSERVATION)

    def _fuse(self, views: list[View], cameras: tuple[PinholeCamera, ...], kind: str):
        """Views -> the top-down colour and height (holes filled as the observation config says)."""
        color, height, covered = fuse_with_coverage(views, cameras, self.world.workspace)
        self.coverage[kind] = float(covered.mean())
        if self.config.sim.observation.fill_holes:
            color, height = fill_holes(color, height, covered, self.sensor.hole_fill)
        return color, height

    def observe(self) -> dict[str, np.ndarray]:
        """A new picture of the current scene, ``{"color", "height"}``; the same as the last step's."""
        self._observe()
        assert self._last_obs is not None
        return {k: v.copy() for k, v in self._last_obs.items()}

    def _observe(self) -> dict:
        color, height = self._fuse(*self.sensed_views(), "obs")
        self._last_obs = {"color": color, "height": height}
        goal = {k: v.copy() for k, v in self._goal.items()}  # new arrays on every call (Gymnasium's rule)
        return {**self._last_obs, "desired_goal": goal}

    def progress(self) -> Progress:
        return evaluate_structure(*self.world.block_poses(), *self.world.target_poses())

    def misses(self, progress: Progress | None = None) -> list[dict]:
        """How each target still unfilled is missed (:func:`tvf.sim.success.target_misses`)."""
        progress = progress or self.progress()
        return target_misses(*self.world.block_poses(), *self.world.target_poses(), progress.block_to_target)

    def _info(self, progress: Progress) -> dict:
        return {
            "task": self.task.name,
            "seed": self.seed_value,
            "success": progress.success,
            "progress": progress.fraction,
            "steps": self.steps,
            "coverage": self.coverage.get("obs", 0.0),
            "misses": self.misses(progress),
        }

    def step(self, action):
        if self.seed_value is None:
            raise TvfError("call reset() before step()")
        if self.terminated:
            raise EpisodeOverError(
                f"the {self.task.name} episode of seed {self.seed_value} has terminated (every block is "
                "placed); call reset() before step()"
            )
        a = validate_action(action)
        before = self.progress().fraction
        result = self.world.arm.pick_and_place(a[0], a[1], set(self.world.blocks))
        self.world.settle()
        self.steps += 1
        progress = self.progress()
        obs = self._observe()
        info = self._info(progress)
        info["primitive"] = result.reason
        terminated = self.terminated = progress.success
        truncated = not terminated and self.steps >= self.max_steps
        return obs, progress.fraction - before, terminated, truncated, info

    def snapshot(self) -> EnvSnapshot:
        """The scene and the episode's counters now, so that actions can be tried and undone with
        :meth:`restore` (the planner's simulated foresight, :mod:`tvf.planning.simulated`). Each snapshot
        holds simulator memory until it is restored without ``keep`` or :meth:`forget`-ed."""
        if self.seed_value is None:
            raise TvfError("call reset() before snapshot()")
        coverage = dict(self.coverage)
        return EnvSnapshot(self.world.save_state(), self.steps, self.terminated, self._last_obs, coverage)

    def restore(self, snapshot: EnvSnapshot, keep: bool = False) -> None:
        """Put the scene and the counters back as they were at ``snapshot`` (``keep``: restorable again)."""
        self.world.restore_state(snapshot.state, remove=not keep)
        self.steps, self.terminated = snapshot.steps, snapshot.terminated
        self._last_obs, self.coverage = snapshot.last_obs, dict(snapshot.coverage)

    def forget(self, snapshot: EnvSnapshot) -> None:
        """Free a snapshot's simulator memory without restoring it."""
        self.world.forget_state(snapshot.state)

    def oracle_action(self, first: int | None = None) -> np.ndarray | None:
        """The expert's next action for the current scene (None when it has nothing to do); ``first``: a
        block to move first if it is off its target (tvf.sim.oracle.oracle_action)."""
        return oracle_action(self.world, self.order, self._oracle_rng, first)

    def random_action(self) -> np.ndarray | None:
        """Move the block the expert would move next to a random free pose (for foresight data)."""
        return random_action(self.world, self.order, self._oracle_rng)

    def render(self) -> np.ndarray | None:
        """The current top-down colour image, uint8 (H, W, 3), in ``rgb_array`` mode (blank before reset)."""
        if self.render_mode != "rgb_array":
            return None
        if self._last_obs is None:
            return np.zeros((*WORKSPACE.shape, 3), np.uint8)
        return self._last_obs["color"].copy()

    def close(self) -> None:
        self.world.close()
