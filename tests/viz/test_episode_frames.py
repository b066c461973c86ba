"""Labelled episode GIFs: the label text, labels drawn where they belong, the legend, the end badge."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import torch

from tvf.evaluate.recording import RecordedEpisode, RecordedStep
from tvf.geometry import pixel_to_world
from tvf.models.images import to_rgbh
from tvf.planning.search import Node, Plan
from tvf.viz import recorded
from tvf.viz.recorded import (
    action_text,
    badge_text,
    episode_frames,
    episode_gif,
    frame_lines,
    legend_items,
    wrap,
)

SIZE = 160


def observation(level: float) -> dict:
    rng = np.random.default_rng(int(level * 100))
    color = rng.integers(0, 255, (SIZE, SIZE, 3), dtype=np.uint8)
    return {"color": color, "height": np.full((SIZE, SIZE), level, np.float32)}


def action(pick_rc, place_rc, turn_deg: float) -> np.ndarray:
    """A (2, 4) action between two pixels, the block turned by ``turn_deg``."""
    (px, py), (qx, qy) = pixel_to_world(np.array(pick_rc)), pixel_to_world(np.array(place_rc))
    return np.array([[px, py, 0.02, 0.3], [qx, qy, 0.06, 0.3 + np.radians(turn_deg)]])


def plan_with_images(depth: int) -> Plan:
    """A chain of ``depth`` imagined nodes (the best path), each with an RGB-H image."""
    nodes = [Node(i, i - 1, i + 1, np.array([10, 10]), np.array([20, 20]), 0, 0.1, 0.9) for i in range(depth)]
    images = torch.cat([to_rgbh(**observation(0.01 * (i + 1))) for i in range(depth)])
    return Plan(nodes, best=depth - 1, images=images)


EPISODE = RecordedEpisode("stack-stair", 7, "TVF-L", 3, 3, success=False)


def steps(with_plans: bool = True) -> list[RecordedStep]:
    goal = observation(0.05)
    acts = [action((80, 60), (40, 97), 90), action((100, 20), (40, 110), -45)]
    out = [
        RecordedStep(observation(0.01 * t), goal, plan_with_images(3 - t) if with_plans else None, a, t / 3)
        for t, a in enumerate(acts)
    ]
    return out + [RecordedStep(observation(0.02), goal, None, None, 2 / 3, None)]


def test_label_text():
    assert action_text(action((80, 60), (40, 97), 90)) == (
        "pick (80, 60) -> place (40, 97) px = (0.439, 0.002) -> (0.555, -0.123) m, turn +90°"
    )
    lines = frame_lines(EPISODE, steps(), 1)
    assert lines[0] == "TVF-L · stack-stair · seed 7 · step 2 of at most 3"
    assert lines[1].startswith("action: pick (100, 20) -> place (40, 110)") and lines[1].endswith("turn -45°")
    assert lines[2] == "progress 1/3 targets"
    end = frame_lines(EPISODE, steps(), 2)
    assert end == ["TVF-L · stack-stair · seed 7 · end after 2 steps", "progress 2/3 targets"]
    assert badge_text(EPISODE, 2 / 3, 2) == "FAILURE: 2/3 targets in 2 steps"
    won = RecordedEpisode("stack-stair", 7, "GCTN", 3, 3, success=True)
    assert badge_text(won, 1.0, 3) == "SUCCESS: 3/3 targets in 3 steps"


def test_gave_up_and_failed_motion_are_named():
    s = steps()
    s[0].primitive = "nothing_to_grasp"
    s[1].action, s[1].primitive = None, "no_action"
    assert frame_lines(EPISODE, s, 0)[1].endswith("(motion: nothing_to_grasp)")
    assert frame_lines(EPISODE, s, 1)[1] == "no action: the policy gave up"


def test_wrap_keeps_lines_inside_the_width():
    text = "action: " + action_text(action((80, 60), (40, 97), 90))
    lines = wrap(text, 300)
    assert len(lines) > 1 and " ".join(lines) == text
    assert all(recorded.font().getlength(line) <= 300 for line in lines if " " in line)


def test_frames_are_labelled_where_the_label_is_drawn():
    frames = episode_frames(EPISODE, steps())
    assert len(frames) == 3 and len({f.shape for f in frames}) == 1  # one GIF size
    bar = recorded.LINE * 3  # the text bar on top
    other = RecordedEpisode("stack-square", 7, "TVF-L", 3, 3, success=False)
    relabelled = episode_frames(other, steps())
    assert not np.array_equal(frames[0][:bar], relabelled[0][:bar])  # the label differs ...
    assert np.array_equal(frames[0][bar + 10 :], relabelled[0][bar + 10 :])  # ... and nothing else
    # the bar is not blank: dark text pixels on white
    assert (frames[0][:bar].min(axis=2) < 80).sum() > 200


def test_columns_show_colour_over_height_and_the_imagined_path():
    frames = episode_frames(EPISODE, steps())
    width = frames[0].shape[1]
    column = SIZE * recorded.SCALE + recorded.GAP
    assert width == 5 * column - recorded.GAP  # real, 3 imagined, goal
    gctn = episode_frames(EPISODE, steps(with_plans=False))
    assert gctn[0].shape[1] == 2 * column - recorded.GAP  # real, goal
    texts = [t for _, _, t in legend_items(imagined=True)]
    assert any("imagined" in t for t in texts) and any("height" in t for t in texts)
    assert not any("imagined" in t for _, _, t in legend_items(imagined=False))


def test_the_last_frame_carries_the_badge(tmp_path):
    frames = episode_frames(EPISODE, steps())
    red = np.all(frames[-1] == recorded.FAILURE, axis=2).sum()
    assert red > 500 and np.all(frames[0] == recorded.FAILURE, axis=2).sum() == 0
    won = episode_frames(RecordedEpisode("stack-stair", 7, "TVF-L", 3, 3, success=True), steps())
    assert np.all(won[-1] == recorded.SUCCESS, axis=2).sum() > 500
    path = episode_gif(tmp_path / "e.gif", EPISODE, steps())
    gif = iio.imread(path, index=None)
    assert gif.shape[0] == 3 and gif.shape[1:3] == frames[0].shape[:2]
    durations = [iio.immeta(path, index=i)["duration"] for i in range(3)]
    assert durations[2] == 2 * durations[0]  # the badge frame shows twice as long
