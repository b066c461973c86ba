"""`tvf demos` and `tvf data info|show`: normal use and bad input answered with one clear line."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from tvf.cli import main
from tvf.data.dataset import MANIFEST
from tvf.data.format import seal


def _fails(argv, capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tvf: error: "), err
    return err[0]


@pytest.fixture
def copy(real_root, tmp_path):
    shutil.copytree(real_root, tmp_path / "demos")
    return tmp_path / "demos"


def test_unknown_task_and_bad_flags(tmp_path, capsys):
    assert "unknown task 'nope'" in _fails(["demos", "--tasks", "nope", "--out", str(tmp_path)], capsys)
    assert "--split must be one of" in _fails(["demos", "--split", "dev", "--out", str(tmp_path)], capsys)
    assert "at least 1" in _fails(["demos", "--episodes", "0", "--out", str(tmp_path)], capsys)
    assert not list(tmp_path.iterdir())


def test_unwritable_output_directory(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    line = _fails(["demos", "--tasks", "stack-stair", "--out", str(blocker / "d")], capsys)
    assert "cannot write to output directory" in line and str(blocker) in line
    assert blocker.read_text() == "not a folder"


def test_demos_rerun_reports_nothing_to_do(copy, capsys):
    main(["demos", "--tasks", "stack-stair", "--episodes", "2", "--out", str(copy)])
    assert "0 episodes written, 2 already there" in capsys.readouterr().out


def test_info_and_show(copy, tmp_path, capsys):
    main(["data", "info", str(copy)])
    out = capsys.readouterr().out
    assert "stack-stair" in out and "per transition" in out
    main(["data", "info", str(copy / "train"), "--verify", "--json"])
    assert '"episodes": 2' in capsys.readouterr().out
    episode = next((copy / "train" / "stack-stair").glob("*.h5"))
    for name in ("ep.gif", "ep.png"):
        main(["data", "show", str(episode), "--out", str(tmp_path / name)])
        assert (tmp_path / name).stat().st_size > 1000
    assert ".gif or .png" in _fails(["data", "show", str(episode), "--out", str(tmp_path / "x.jpg")], capsys)


def test_corrupt_episode_is_named_and_kept(copy, tmp_path, capsys):
    episode = sorted((copy / "train" / "stack-stair").glob("*.h5"))[0]
    data = bytearray(episode.read_bytes())
    for i in np.random.default_rng(0).integers(len(data) // 3, len(data), 64):
        data[i] ^= 0xFF
    episode.write_bytes(bytes(data))
    assert str(episode) in _fails(["data", "show", str(episode), "--out", str(tmp_path / "x.gif")], capsys)
    assert str(episode) in _fails(["data", "info", str(copy), "--verify"], capsys)
    assert episode.read_bytes() == bytes(data)  # never deleted or rewritten


def test_dataset_of_another_format_version(copy, capsys):
    episode = sorted((copy / "train" / "stack-stair").glob("*.h5"))[0]
    with h5py.File(episode, "r+") as f:
        f.attrs["format_version"] = 0
    seal(episode)  # as another version of tvf would have written it
    (copy / "train" / MANIFEST).unlink()
    line = _fails(["data", "info", str(copy)], capsys)
    assert str(episode) in line and "format version 0" in line
    line = _fails(["demos", "--tasks", "stack-stair", "--episodes", "2", "--out", str(copy)], capsys)
    assert str(episode) in line and episode.exists()


def test_missing_dataset(tmp_path, capsys):
    assert "no such dataset directory" in _fails(["data", "info", str(tmp_path / "none")], capsys)
    assert "no such episode file" in _fails(
        ["data", "show", str(tmp_path / "x.h5"), "--out", str(tmp_path / "x.gif")], capsys
    )


def test_a_nested_split_is_named(copy, tmp_path, capsys):
    nested = tmp_path / "made" / "train"
    shutil.copytree(copy / "train", nested / "train")  # `tvf demos --out made/train` wrote made/train/train
    line = _fails(["data", "info", str(nested)], capsys)
    assert "holding another split" in line and str(nested / "train") in line
