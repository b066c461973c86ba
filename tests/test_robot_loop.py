"""The robot interface: the simulator behind `tvf.robot.Robot` closes the loop with `tvf.load_planner` and
takes the same actions to the same outcome as the episode loop of `tvf eval`."""

import numpy as np
import pytest

import tvf
from tvf.errors import TvfError
from tvf.evaluate.runner import policy_episode
from tvf.policies import PolicySpec
from tvf.robot import Outcome, Robot, SimRobot, run_on_robot
from tvf.sim.env import TvfEnv
from tvf.tasks import get_task

TASK = get_task("stack-tower")


@pytest.fixture(scope="module")
def robot():
    env = TvfEnv(TASK)
    yield SimRobot(env)
    env.close()


def test_the_simulator_implements_the_robot_protocol(robot):
    assert isinstance(robot, Robot)


def test_the_robot_loop_matches_the_episode_loop(robot):
    reference = policy_episode(TASK, 1, PolicySpec("gctn"))
    goal = robot.start(1)
    seen = []
    run = run_on_robot(robot, tvf.load_planner("gctn"), goal, TASK.horizon, done=robot.done,
                       on_decision=lambda obs, d: seen.append(obs["height"].max()))  # fmt: skip
    assert run.actions == reference.actions and len(seen) == len(run.decisions)
    assert [o.reason for o in run.outcomes] == reference.primitives
    assert robot.done() == reference.success and (run.stopped == "done") == reference.success
    assert robot.info["progress"] == reference.progress


class ScriptedArm:
    """A robot whose every motion fails, to test the stop rules without a simulator."""

    def __init__(self):
        self.calls = []

    def observe(self):
        return {"color": np.zeros((160, 160, 3), np.uint8), "height": np.zeros((160, 160), np.float32)}

    def pick_and_place(self, pick, place):
        self.calls.append("pick_and_place")
        return Outcome(False, "no_pick_contact")

    def home(self):
        self.calls.append("home")


def test_the_loop_stops_on_a_failed_motion_when_asked():
    arm, planner = ScriptedArm(), tvf.load_planner("gctn")
    goal = {"color": np.zeros((160, 160, 3), np.uint8), "height": np.full((160, 160), 0.02, np.float32)}
    run = run_on_robot(arm, planner, goal, 3, stop_on_failure=True)
    assert run.stopped == "robot_failed" and arm.calls == ["home", "pick_and_place"]
    assert run_on_robot(ScriptedArm(), planner, goal, 2).stopped == "max_steps"
    with pytest.raises(TvfError, match="max_steps must be at least 1"):
        run_on_robot(arm, planner, goal, 0)
