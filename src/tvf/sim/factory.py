"""The simulator as an environment factory (the default of every command that runs episodes).

``SimEnvFactory(sensor="d415-one")`` is the simulator seen through another sensor (tvf.sim.sensors); the
named factories below are what ``tvf eval --env tvf.sim.factory:NAME`` takes (docs/real-robot.md).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from tvf.sim.env import TvfEnv
from tvf.sim.sensors import SensorConfig, get_sensor
from tvf.tasks import Task

_ENVS: dict[tuple[Task, bool, SensorConfig, int], TvfEnv] = {}


@dataclass(frozen=True)
class SimEnvFactory:
    """One PyBullet environment per task, sensor, slot and process, created on first use (a picklable value).

    ``slot`` tells apart the environments of one task that a process steps side by side
    (`tvf eval --envs-per-worker`); each slot is a world of its own.
    """

    gui: bool = False
    """Open a PyBullet window (needs a display; one process)."""
    sensor: str | SensorConfig = "ideal"
    """The cameras: a name of tvf.sim.sensors.SENSORS or a SensorConfig (checked on construction)."""

    def __post_init__(self) -> None:
        get_sensor(self.sensor)  # an unknown name fails here, in the parent, not in a worker

    @property
    def ideal(self) -> bool:
        """The simulator's own perfect three cameras (today's observations)."""
        return get_sensor(self.sensor) == SensorConfig()

    def describe(self) -> str | dict:
        """The sensor as an evaluation records it: the preset's name, or every field of a custom config."""
        return self.sensor if isinstance(self.sensor, str) else asdict(self.sensor)

    def __call__(self, task: Task, slot: int = 0) -> TvfEnv:
        sensor = get_sensor(self.sensor)
        key = (task, self.gui, sensor, slot)
        if key not in _ENVS:
            _ENVS[key] = TvfEnv(task, gui=self.gui, sensor=sensor)
        return _ENVS[key]


def sim_env(task: Task) -> TvfEnv:
    """This process's headless simulator for ``task``."""
    return SimEnvFactory()(task)


ONE = SimEnvFactory(sensor="one")
"""One perfect camera in front of the workspace (occlusion holes, no noise)."""
D415 = SimEnvFactory(sensor="d415")
"""The three cameras with D415-like depth noise, dropout and 1 mm depth units."""
D415_ONE = SimEnvFactory(sensor="d415-one")
"""One D415-like camera: the paper's real set-up."""
D415_ONE_CALIB = SimEnvFactory(sensor="d415-one-calib")
"""One D415-like camera whose pose is off by 3 mm and 1 degree (drawn per episode)."""
D415_ONE_CALIB_LEVEL = SimEnvFactory(sensor="d415-one-calib-level")
"""That miscalibrated camera, levelled on the table before each fusion (tilt and height corrected)."""
D415_ONE_GOAL2 = SimEnvFactory(sensor="d415-one-goal2")
"""One D415-like camera for the scene; the goal recorded with it from in front and from behind."""
D435_ONE = SimEnvFactory(sensor="d435-one")
"""One camera with the D435's noise (2.5 times the D415's)."""
