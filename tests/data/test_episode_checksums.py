"""Episode checksums: the seal (the file's bytes) is checked before HDF5 parses them and every array and
attribute after; a flipped byte anywhere in a file is harmless or a DataError naming it (never other data,
never another exception, never a crash), `--verify` names every damaged file, `tvf train` refuses one,
and format 1 files (neither) are read with a warning."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest
from data_factory import make_episode

from tvf.cli import main
from tvf.data import DataError, read_episode, read_frames, read_info, write_episode, write_manifest
from tvf.data.dataset import MANIFEST, scan, verify
from tvf.data.format import CHECKSUMS, FORMAT_VERSION, SEAL_MAGIC, Episode, episode_name, seal

FIELDS = ("color", "height", "pick", "place", "random", "progress", "blocks", "targets")


def _small_episode() -> Episode:
    """Two steps of flat images: a 32 KB file, mostly HDF5 metadata (where a flip used to go unnoticed)."""
    ep = make_episode(steps=2)
    ep.color[:] = 100
    ep.height[:] = 0.01
    return ep


def _same(a: Episode, b: Episode) -> bool:
    arrays = all(
        getattr(a, n).dtype == getattr(b, n).dtype
        and np.array_equal(np.asarray(getattr(a, n)), getattr(b, n))
        for n in FIELDS
    )
    return (
        arrays
        and a.attrs == b.attrs
        and (a.task, a.seed, a.split, a.success) == (b.task, b.seed, b.split, b.success)
    )


def _outcome(path: Path, reference: Episode, info) -> str:
    """'harmless' (every reader sees the original episode) or 'reported' (a one-line DataError naming the
    file); a silent change or any other exception fails the test."""
    try:
        readers = {
            "read_episode": lambda: _same(read_episode(path), reference),
            "lazy": lambda: _same(read_episode(path, lazy=True), reference),
            "read_info": lambda: read_info(path) == info,
        }
        for name, same in readers.items():
            assert same(), f"{name} read other data from {path} without an error"
    except DataError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc), exc
        return "reported"
    return "harmless"


def _sweep(tmp_path: Path, positions: int | None, masks: tuple[int, ...]) -> dict[str, int]:
    """Flip one byte at ``positions`` evenly spaced places (None: every byte) with each mask."""
    source = tmp_path / "source" / episode_name(0)
    write_episode(source, _small_episode())
    reference, good = read_episode(source), source.read_bytes()
    path = tmp_path / "flipped" / episode_name(0)
    path.parent.mkdir()
    info = replace(read_info(source), path=path)  # the same header, read from the flipped copy
    path.write_bytes(good)
    counts = {"harmless": 0, "reported": 0}
    places = range(len(good)) if positions is None else np.linspace(0, len(good) - 1, positions).astype(int)
    for mask in masks:
        for i in places:
            data = bytearray(good)
            data[i] ^= mask
            path.unlink()  # a new file (lazy readers keep files open: never the same one rewritten)
            path.write_bytes(bytes(data))
            try:
                counts[_outcome(path, reference, info)] += 1
            except AssertionError as exc:
                raise AssertionError(f"byte {i} ^ {mask:#x}: {exc}") from None
    return counts


def test_a_byte_flip_sweep_over_an_episode_is_harmless_or_reported(tmp_path):
    counts = _sweep(tmp_path, 40, (0xFF,))
    assert sum(counts.values()) == 40 and counts["reported"] > 0


@pytest.mark.slow
def test_the_full_byte_flip_sweep_over_an_episode(tmp_path):
    counts = _sweep(tmp_path, None, (0xFF, 0x01))  # every byte of the 32 KB file, twice
    print(f"episode byte-flip sweep: {counts}")
    assert sum(counts.values()) > 60_000 and counts["reported"] > 0


def _damage(path: Path, edit, reseal: bool = True) -> Path:
    """Change a file through HDF5 and (as another writer would) seal it again, so that the content
    checksums are what catches the change."""
    with h5py.File(path, "r+") as f:
        edit(f)
    if reseal:
        seal(path)
    return path


@pytest.fixture
def stored(tmp_path, episode) -> Path:
    path = tmp_path / "stack-stair" / episode_name(0)
    write_episode(path, episode)
    return path


@pytest.mark.parametrize(
    ("edit", "what"),
    [
        (lambda f: f["pick"].__setitem__((0, 0), 0.5), "dataset 'pick'"),
        (lambda f: f["blocks"].__setitem__((1, 0, 2), 0.0), "dataset 'blocks'"),
        (lambda f: f["random"].__setitem__(1, True), "dataset 'random'"),
        (lambda f: f.attrs.__setitem__("seed", 2), "attributes"),
        (lambda f: f.attrs.__setitem__("primitives", '["ok"]'), "attributes"),
        (lambda f: f.attrs.__setitem__("new", 1), "attributes"),
        (lambda f: f.attrs.__delitem__(CHECKSUMS), "no 'sha256' attribute"),
        (lambda f: f.attrs.__setitem__(CHECKSUMS, "{}"), "malformed"),
    ],
)
def test_every_array_and_attribute_is_checked(stored, edit, what):
    _damage(stored, edit)
    for read in (read_episode, read_info):
        with pytest.raises(DataError, match=rf"{stored}: .*{what}.*damaged.*re-run `tvf demos`"):
            read(stored)


def test_a_file_changed_after_tvf_wrote_it_breaks_its_seal(stored):
    assert stored.read_bytes().startswith(SEAL_MAGIC)
    _damage(stored, lambda f: f.attrs.__setitem__("seed", 2), reseal=False)
    for read in (read_episode, read_info, lambda p: read_episode(p, lazy=True)):
        with pytest.raises(DataError, match=rf"{stored}: its bytes do not match the SHA-256 in its first"):
            read(stored)


def test_a_changed_frame_is_caught_by_every_reader(stored):
    _damage(stored, lambda f: f["height"].__setitem__((3, 10, 10), 0.2))
    read_info(stored)  # the header and the small fields are intact
    with pytest.raises(DataError, match=r"frame 3 of 'height' does not match its SHA-256"):
        read_episode(stored)
    lazy = read_episode(stored, lazy=True)
    assert np.array_equal(lazy.height[2], read_frames(stored, [2])[1][0])  # other frames read fine
    with pytest.raises(DataError, match=r"frame 3 of 'height'"):
        lazy.height[3]
    with pytest.raises(DataError, match=r"frame 3 of 'height'"):
        read_frames(stored, [0, 3])


def test_a_file_rewritten_under_a_lazy_episode_is_reopened_and_checked(stored):
    lazy = read_episode(stored, lazy=True)
    first = lazy.color[0]
    stored.unlink()
    write_episode(stored, make_episode(rng_seed=1))  # another episode of the same shape, at the same path
    with pytest.raises(DataError, match=r"frame 0 of 'color' does not match its SHA-256"):
        lazy.color[0]
    assert first.shape == (160, 160, 3)


def test_a_grown_dataset_is_refused_before_it_is_read(stored):
    """A damaged shape used to read back zeros for the missing chunks; now the layout is checked first."""

    def grow(f):
        del f["progress"]
        f.create_dataset("progress", data=np.zeros(9, np.float32))

    _damage(stored, grow)
    with pytest.raises(DataError, match=r"dataset 'progress' has shape \(9,\)"):
        read_episode(stored)


def test_the_same_episode_gives_the_same_bytes(tmp_path, episode):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    write_episode(a, episode)
    write_episode(b, episode)
    assert a.read_bytes() == b.read_bytes()
    with h5py.File(a) as f:
        assert f.attrs["format_version"] == FORMAT_VERSION == 2
        sums = json.loads(f.attrs[CHECKSUMS])
    assert len(sums["color"]) == len(sums["height"]) == episode.n_steps + 1


def _as_format_1(path: Path) -> Path:
    """What tvf wrote before checksums: the same datasets and attributes, without the seal (no user
    block) and the checksums attribute, version 1."""
    new = path.with_name("old.h5")
    with h5py.File(path) as a, h5py.File(new, "w") as b:
        for name in a:
            a.copy(name, b)
        b.attrs.update({k: v for k, v in a.attrs.items() if k != CHECKSUMS})
        b.attrs["format_version"] = 1
    new.replace(path)
    return path


def test_format_1_files_are_read_unverified_with_one_warning_per_folder(tmp_path, episode, capsys):
    folder = tmp_path / "old" / "train"
    for seed in (0, 2):
        path = folder / "stack-stair" / episode_name(seed)
        write_episode(path, episode)
        _as_format_1(path)
    back = read_episode(folder / "stack-stair" / episode_name(0))
    read_episode(folder / "stack-stair" / episode_name(2))
    assert _same(back, read_episode(folder / "stack-stair" / episode_name(0)))
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "format version 1" in err[0] and "unverified" in err[0], err
    assert str(folder / "stack-stair") in err[0] and "tvf demos" in err[0]
    assert read_info(folder / "stack-stair" / episode_name(0)).checksum is None
    old_manifest = {"format_version": 1, "files": []}  # an older manifest: rebuilt from the files
    (folder / MANIFEST).write_text(json.dumps(old_manifest))
    assert len(scan(folder)) == 2
    check = verify(folder)
    assert check.unverified == 2 and not check.failures


@pytest.fixture
def dataset(tmp_path) -> Path:
    """A train split of two tasks, two episodes each, with its manifest."""
    root = tmp_path / "demos"
    for task in ("stack-stair", "put-t"):
        for seed in (0, 2):
            write_episode(
                root / "train" / task / episode_name(seed), make_episode(task, seed, 3, "train", seed)
            )
    write_manifest(scan(root / "train"))
    return root


def _fails(argv, capsys) -> tuple[str, str]:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tvf: error: "), lines
    return lines[0], out


def test_verify_names_every_damaged_file(dataset, capsys):
    main(["data", "info", str(dataset), "--verify"])
    assert "verified: every file matches its checksums" in capsys.readouterr().out
    bad = [dataset / "train" / "stack-stair" / episode_name(2), dataset / "train" / "put-t" / episode_name(0)]
    _damage(bad[0], lambda f: f["place"].__setitem__((1, 3), 1.0))
    _damage(bad[1], lambda f: f.attrs.__setitem__("success", False))
    line, out = _fails(["data", "info", str(dataset), "--verify"], capsys)
    assert "2 damaged episode files" in line and all(str(p) in line for p in bad)
    assert "re-run `tvf demos`" in line
    assert "dataset 'place' does not match" in out and "the attributes do not match" in out
    assert "put-t" in out and "stack-stair" in out  # the table of the intact files is printed


def test_verify_compares_each_file_with_the_manifest(dataset):
    doc = json.loads((dataset / "train" / MANIFEST).read_text())
    assert all(len(d["checksum"]) == 64 for d in doc["files"])
    doc["files"][0]["checksum"] = "0" * 64  # as if the file had been replaced by another of its size
    (dataset / "train" / MANIFEST).write_text(json.dumps(doc))
    check = verify(dataset / "train")
    assert [p.relative_to(dataset / "train").as_posix() for p in check.failures] == [doc["files"][0]["path"]]
    assert "differs from its record in manifest.json" in next(iter(check.failures.values()))


def test_verify_lists_an_unreadable_manifest_and_still_checks_every_file(dataset):
    (dataset / "train" / MANIFEST).write_text("{ not json")
    bad = dataset / "train" / "put-t" / episode_name(2)
    _damage(bad, lambda f: f["pick"].__setitem__((0, 1), 0.0))
    check = verify(dataset / "train")
    assert sorted(check.failures) == sorted([dataset / "train" / MANIFEST, bad])
    assert "unreadable manifest" in check.failures[dataset / "train" / MANIFEST]


def test_train_refuses_a_damaged_file_by_name_before_training(dataset, tmp_path, capsys):
    bad = dataset / "train" / "put-t" / episode_name(2)
    _damage(bad, lambda f: f["pick"].__setitem__((0, 1), 0.0))
    out = tmp_path / "run"
    argv = ["train", "gctn", "--data", str(dataset), "--demos", "2", "--preset", "smoke", "--steps", "1",
            "--tasks", "stack-stair,put-t", "--out", str(out)]  # fmt: skip
    line, _ = _fails(argv, capsys)
    assert str(bad) in line and "does not match its SHA-256" in line and "tvf demos" in line
    assert not (out / "checkpoints").exists() or not any((out / "checkpoints").iterdir())


def test_a_text_file_named_h5_is_one_line(tmp_path, capsys):
    folder = tmp_path / "d" / "train" / "stack-stair"
    folder.mkdir(parents=True)
    (folder / episode_name(0)).write_text("not an episode\n")
    line, out = _fails(["data", "info", str(tmp_path / "d"), "--verify"], capsys)
    assert str(folder / episode_name(0)) in line and "not a readable HDF5 episode" in out
