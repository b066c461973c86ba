"""`tvf demos --sensor`: demonstrations recorded through a noisy rig, one sensor per split folder."""

import json

import numpy as np
import pytest

from tvf.data.format import DataError, read_episode
from tvf.data.generation import SENSOR_FILE, GenerationPlan, generate
from tvf.sim.env import TvfEnv


def test_demos_are_recorded_through_the_sensor_and_folders_do_not_mix(tmp_path):
    plan = GenerationPlan(("stack-tower",), "test", 1, tmp_path, sensor="d415-one")
    report = generate(plan, progress=False)
    assert report.generated == 1 and (plan.folder / SENSOR_FILE).is_file()
    path = next(plan.folder.glob("stack-tower/*.h5"))
    episode = read_episode(path)
    env = TvfEnv("stack-tower", sensor="d415-one")
    try:
        obs, _ = env.reset(seed=episode.seed)
    finally:
        env.close()
    assert np.array_equal(episode.height[0], obs["height"]) and np.array_equal(episode.color[0], obs["color"])
    assert episode.attrs["sensor"]["name"] == "d415-one" and len(episode.attrs["observation"]["cameras"]) == 1
    assert episode.attrs["sensor"]["hole_fill"] == "background"
    assert json.loads((plan.folder / SENSOR_FILE).read_text()) == {
        "sensor": "d415-one",
        "hole_fill": "background",
    }
    with pytest.raises(DataError, match="recorded through the 'd415-one' sensor; pass --sensor d415-one"):
        generate(GenerationPlan(("stack-tower",), "test", 2, tmp_path), progress=False)
    with pytest.raises(DataError, match="recorded through the 'ideal' sensor"):
        ideal = GenerationPlan(("stack-tower",), "test", 1, tmp_path / "ideal")
        generate(ideal, progress=False)
        generate(
            GenerationPlan(("stack-tower",), "test", 1, tmp_path / "ideal", sensor="d415"), progress=False
        )


def test_a_folder_of_the_older_one_camera_filling_is_not_resumed(tmp_path):
    plan = GenerationPlan(("stack-tower",), "test", 1, tmp_path, sensor="one")
    plan.folder.mkdir(parents=True)
    (plan.folder / SENSOR_FILE).write_text(json.dumps({"sensor": "one"}))  # as the previous version wrote it
    with pytest.raises(DataError, match="whose holes were filled 'nearest' .* fills them 'background'"):
        generate(plan, progress=False)
