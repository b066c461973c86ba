"""The episode file: round trip, pixel conventions, and clear errors for damaged or foreign files."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from data_factory import make_episode
from hypothesis import given, settings
from hypothesis import strategies as st

from tvf.data import (
    FORMAT_VERSION,
    DataError,
    read_episode,
    read_frames,
    read_info,
    seal,
    subpixel_to_pixel,
    world_to_subpixel,
    write_episode,
)
from tvf.geometry import WORKSPACE, pixel_to_world, world_to_pixel


def test_round_trip_is_exact(tmp_path, episode):
    path = tmp_path / "stack-stair" / "000000.h5"
    size = write_episode(path, episode)
    assert size == path.stat().st_size
    back = read_episode(path)
    for name in ("color", "height", "pick", "place", "random", "progress", "blocks", "targets"):
        a, b = getattr(episode, name), getattr(back, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert (back.task, back.seed, back.split, back.success) == ("stack-stair", 0, "train", True)
    assert back.attrs["format_version"] == FORMAT_VERSION
    assert back.attrs["primitives"] == ["ok"] * 5
    assert back.attrs["workspace"]["pixel_size"] == WORKSPACE.pixel_size
    info = read_info(path)
    assert (info.steps, info.random_steps, info.bytes) == (5, 2, size)
    color, height = read_frames(path, np.array([3, 0, 3]))
    assert np.array_equal(color, episode.color[[3, 0, 3]])
    assert np.array_equal(height, episode.height[[3, 0, 3]])
    assert not list(tmp_path.rglob(".*"))  # no temporary file left


def test_goal_is_the_last_frame_and_actions_become_pixels(episode):
    assert np.array_equal(episode.goal_color, episode.color[-1])
    assert np.array_equal(episode.pick_pixels(), world_to_pixel(episode.pick[:, :2]))
    assert episode.rotation_bins(36).shape == (5,)


def test_a_failed_write_leaves_nothing(tmp_path, episode):
    episode.height = episode.height.astype(np.float64)  # wrong dtype: refused before writing
    path = tmp_path / "t" / "000000.h5"
    with pytest.raises(DataError, match="height"):
        write_episode(path, episode)
    assert not any(p.is_file() for p in tmp_path.rglob("*"))


@settings(max_examples=200, deadline=None)
@given(st.floats(0.25, 0.75 - 1e-9), st.floats(-0.25, 0.25 - 1e-9))
def test_subpixel_frame_matches_the_floor_rule(x, y):
    xy = np.array([x, y])
    sub = world_to_subpixel(xy)
    assert np.allclose(pixel_to_world(sub), xy, atol=1e-12)
    px = subpixel_to_pixel(sub)
    # the floor rule, except where float rounding sits exactly on a pixel edge
    assert np.abs(px - world_to_pixel(xy)).max() <= (0 if np.abs(sub % 1 - 0.5).min() > 1e-9 else 1)


def test_pixel_centres_are_integer_subpixels():
    rc = np.array([[0, 0], [17, 151], [159, 159]])
    assert np.allclose(world_to_subpixel(pixel_to_world(rc)), rc)


def _flip(path, start_fraction: float, count: int = 64) -> None:
    data = bytearray(path.read_bytes())
    rng = np.random.default_rng(0)
    for i in rng.integers(int(len(data) * start_fraction), len(data), count):
        data[i] ^= 0xFF
    path.write_bytes(bytes(data))


def test_flipped_bytes_raise_a_clear_error_naming_the_file(tmp_path, episode):
    path = tmp_path / "ep.h5"
    write_episode(path, episode)
    _flip(path, 0.3)
    with pytest.raises(DataError, match=str(path)):
        read_episode(path)


def test_truncated_and_missing_files(tmp_path, episode):
    path = tmp_path / "ep.h5"
    write_episode(path, episode)
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(DataError, match=rf"{path}.*(truncated|corrupt)"):
        read_episode(path)
    with pytest.raises(DataError, match="no such episode file"):
        read_episode(tmp_path / "missing.h5")
    (tmp_path / "empty.h5").write_bytes(b"")
    with pytest.raises(DataError, match="empty.h5"):
        read_info(tmp_path / "empty.h5")


def test_other_format_version_is_refused(tmp_path, episode):
    path = tmp_path / "ep.h5"
    write_episode(path, episode)
    with h5py.File(path, "r+") as f:
        f.attrs["format_version"] = FORMAT_VERSION + 1
    seal(path)  # as another version of tvf would have written it
    with pytest.raises(DataError, match=rf"{path}: episode format version {FORMAT_VERSION + 1}"):
        read_episode(path)


def test_foreign_hdf5_file_is_refused(tmp_path):
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(DataError, match="not a tvf episode file"):
        read_info(path)
    with h5py.File(path, "a") as f:
        header = {"format_version": FORMAT_VERSION, "task": "t", "seed": 0, "split": "train", "success": 1}
        f.attrs.update(header)
    with pytest.raises(DataError, match="lacks"):
        read_episode(path)


def test_episode_of_another_task_size_round_trips(tmp_path):
    ep = make_episode("stack-pallet", seed=8, steps=10, split="test")
    path = tmp_path / "p.h5"
    write_episode(path, ep)
    back = read_episode(path)
    assert back.n_steps == 10 and back.n_random == 0 and back.split == "test"
