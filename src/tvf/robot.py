"""The robot interface: what closing the loop on an arm needs, with the simulator as its reference.

A :class:`Robot` takes pictures and executes pick-and-places; :func:`run_on_robot` closes the loop with a
planner of :func:`tvf.load_planner`: observe, plan one step towards the goal image, pick and place,
until a step budget or a stop test says enough. :class:`SimRobot` is the simulator behind the same three
calls, so the loop is tested here exactly as it would run on an arm (docs/real-robot.md).

A real arm implements ``observe`` by recording its cameras and fusing them (``tvf.views.load_rgbh`` on a
recorded views folder, or ``tvf.fusion.fuse`` on live frames), ``pick_and_place`` with its own motion
(the simulator's primitive is the reference: docs/world.md), and ``home`` by moving out of the cameras'
view. Every pose is in the robot base frame (docs/conventions.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from tvf.api import Decision, Planner
from tvf.envs import Observation
from tvf.errors import TvfError
from tvf.sim.env import TvfEnv


@dataclass(frozen=True)
class Outcome:
    """What one pick-and-place did, as the robot saw it."""

    ok: bool
    """Whether the motion completed (the block was grasped and released)."""
    reason: str = "ok"
    """``ok`` or why not, in the robot's words (the simulator's: no_pick_contact, nothing_to_grasp, ...)."""


@runtime_checkable
class Robot(Protocol):
    """An arm with a suction cup (or gripper) and a calibrated camera rig."""

    def observe(self) -> Observation:
        """The top-down image of the workspace now: ``{"color": uint8 (160, 160, 3), "height": float32
        (160, 160) metres above the table}`` (docs/observation.md)."""
        ...

    def pick_and_place(self, pick: np.ndarray, place: np.ndarray) -> Outcome:
        """Pick at ``pick`` and place at ``place``, each (x, y, z, yaw) in the base frame (metres, radians;
        z the top of the block at the pick, of the placed block at the place; the block turns by
        place yaw - pick yaw), then return to where the cameras see the workspace."""
        ...

    def home(self) -> None:
        """Move out of the cameras' view (before the first picture)."""
        ...


@dataclass
class RobotRun:
    """What :func:`run_on_robot` did: the decisions, the robot's outcomes, and why it stopped."""

    decisions: list[Decision] = field(default_factory=list)
    outcomes: list[Outcome] = field(default_factory=list)
    stopped: str = "max_steps"
    """``done`` (the stop test said so), ``max_steps`` or ``robot_failed`` (with ``stop_on_failure``)."""

    @property
    def actions(self) -> list[list[list[float]]]:
        """The ``(2, 4)`` actions as lists, as the episode records of `tvf eval` hold them."""
        return [d.as_array().tolist() for d in self.decisions]


def run_on_robot(
    robot: Robot, planner: Planner, goal: Observation, max_steps: int,
    done: Callable[[], bool] | None = None, stop_on_failure: bool = False,
    on_decision: Callable[[Observation, Decision], None] | None = None,
) -> RobotRun:  # fmt: skip
    """Close the loop: ``home``, then up to ``max_steps`` times observe, plan towards ``goal`` (an image of
    the finished structure, e.g. fused from a views folder) and pick and place.

    ``done()`` is asked after every step (a person at the keyboard, or the simulator's success test);
    ``on_decision(obs, decision)`` sees each decision before it runs (to log it or to ask for consent).
    """
    if max_steps < 1:
        raise TvfError(f"max_steps must be at least 1, not {max_steps}")
    run = RobotRun()
    robot.home()
    for _ in range(max_steps):
        obs = robot.observe()
        decision = planner.next_action(obs["color"], obs["height"], goal["color"], goal["height"])
        if on_decision is not None:
            on_decision(obs, decision)
        outcome = robot.pick_and_place(decision.pick, decision.place)
        run.decisions.append(decision)
        run.outcomes.append(outcome)
        if done is not None and done():
            run.stopped = "done"
            break
        if stop_on_failure and not outcome.ok:
            run.stopped = "robot_failed"
            break
    return run


class SimRobot:
    """The simulator as a :class:`Robot` (the reference implementation), over a :class:`TvfEnv`.

    ``start(seed)`` lays out an episode's scene and returns its goal image; ``done()`` is the simulator's
    success test (a real robot has none: a person or a vision check decides).
    """

    def __init__(self, env: TvfEnv) -> None:
        self.env = env
        self.info: dict = {}
        """The environment's info of the last reset or step (success, progress, steps, coverage)."""

    def start(self, seed: int) -> Observation:
        """Reset the scene to ``seed``; the goal image, seen through the environment's sensor."""
        _, self.info = self.env.reset(seed=seed)
        return self.info["goal"]

    def observe(self) -> Observation:
        return self.env.observe()

    def pick_and_place(self, pick: np.ndarray, place: np.ndarray) -> Outcome:
        action = np.stack([np.asarray(pick, dtype=np.float64), np.asarray(place, dtype=np.float64)])
        _, _, _, _, self.info = self.env.step(action)
        reason = str(self.info["primitive"])
        return Outcome(reason == "ok", reason)

    def home(self) -> None:
        """The simulated arm is lifted out of the cameras' view for every picture; nothing to do."""

    def done(self) -> bool:
        """Whether the structure is finished (the simulator's success test)."""
        return bool(self.info.get("success", False))
