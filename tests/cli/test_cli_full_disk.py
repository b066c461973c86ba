"""A full disk (issue 16, case 3): `tvf demos`, `tvf train` and `tvf eval` stop with one line and exit
code 2, leave no temporary file and no torn log line, and a re-run after freeing space gives the bytes
of an uninterrupted run. The disk is faked (tests/cli/disk_fakes.py); the tests at the end use a real
small tmpfs where mounting is allowed (root) and skip otherwise."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_run import run
from data_factory import make_episode
from disk_fakes import FakeDisk

import tvf.data.generation as generation
from tvf.data.format import episode_name, write_episode
from tvf.io import as_disk_full


def full_disk_error(capsys, *args: str) -> str:
    """Run `tvf ARGS` expecting the one-line full-disk error; returns that line."""
    code, out, err = run(capsys, *args)
    assert code == 2, (out, err)
    assert "Traceback" not in err
    errors = [line for line in err.splitlines() if line.startswith("tvf: error:")]
    assert len(errors) == 1 and errors[0].startswith("tvf: error: no space left on "), err
    assert errors[0].endswith("; free space and re-run the same command to resume") or errors[0].endswith(
        "; free space and re-run the same command with --resume to continue"
    )
    return errors[0]


def no_temporary_files(root: Path) -> None:
    assert not [p for p in root.rglob("*") if p.name.endswith(".tmp")]


def whole_lines(path: Path) -> list[dict]:
    """The records of a JSON-lines file that must hold whole lines only ([] when missing)."""
    text = path.read_text() if path.exists() else ""
    assert text == "" or text.endswith("\n"), f"{path} ends in a torn line"
    return [json.loads(line) for line in text.splitlines()]


def files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------------------------ tvf demos
FAILING_SEED = 2


def scripted_episode(task, split: str, seed: int, sensor: str = "ideal", near_misses: int = 0):
    """The episode job's simulation, replaced: small synthetic episodes; seed 2 fails (failures.jsonl)."""
    name = task if isinstance(task, str) else task.name
    if seed == FAILING_SEED:
        return None, generation.Outcome(name, seed, False, reason="scripted failure", steps=1)
    ep = make_episode(name, seed, steps=2, split=split, rng_seed=seed)
    ep.color, ep.height = np.zeros_like(ep.color), np.zeros_like(ep.height)  # small files
    return ep, generation.Outcome(name, seed, True, steps=2, primitives=["ok", "ok"])


DEMOS = ("demos", "--tasks", "stack-stair,stack-tower", "--episodes", "2")


@pytest.fixture
def demos_disk(monkeypatch, tmp_path, capsys):
    """A fake disk, after an uninterrupted run into tmp_path/full."""
    monkeypatch.setattr(generation, "collect_episode", scripted_episode)
    disk = FakeDisk(monkeypatch)
    code, _, err = run(capsys, *DEMOS, "--out", str(tmp_path / "full"))
    assert code == 0, err
    return disk


@pytest.mark.parametrize(
    ("target", "occurrence", "kept"),
    [
        ("000004.h5", 1, 2),  # stack-stair's seed 4: seed 0 of both tasks is kept
        ("failures.jsonl", 2, 2),  # stack-tower's failed seed 2, cut mid-line (stack-stair's is kept)
        ("manifest.json", 1, 4),  # every episode is on disk; only the summary is missing
    ],
)
def test_demos_on_a_full_disk(demos_disk, tmp_path, capsys, target, occurrence, kept):
    disk = demos_disk
    disk.fill_during(target, occurrence)
    out = tmp_path / "part"
    line = full_disk_error(capsys, *DEMOS, "--out", str(out))
    assert disk.filled
    assert f"{kept} episodes kept in {out / 'train'}" in line and target.split(".")[0] in line
    no_temporary_files(out)
    failures = whole_lines(out / "train" / "failures.jsonl")
    logged = [(r["task"], r["seed"]) for r in failures]
    assert logged == [("stack-stair", 2), ("stack-tower", 2)][: len(logged)]
    disk.free = None  # space freed
    code, _, err = run(capsys, *DEMOS, "--out", str(out))
    assert code == 0, err
    assert files(out) == files(tmp_path / "full")


# ------------------------------------------------------------------------------------ tvf train
TRAIN_TASKS = ("stack-stair", "put-t")


@pytest.fixture(scope="module")
def train_data(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("demos")
    for split, seeds in (("train", (0, 2)), ("test", (1,))):
        for task in TRAIN_TASKS:
            for seed in seeds:
                ep = make_episode(task, seed, steps=3, split=split, rng_seed=seed)
                write_episode(root / split / task / episode_name(seed), ep)
    return root


@pytest.fixture(scope="module")
def train_full(train_data, tmp_path_factory) -> Path:
    """An uninterrupted training run, shared by the tests."""
    from tvf.cli import main

    out = tmp_path_factory.mktemp("train") / "full"
    main(list(train_args(train_data, out)))
    return out


def train_args(data: Path, out: Path, *extra: str) -> tuple[str, ...]:
    return ("train", "gctn", "--data", str(data), "--out", str(out), "--tasks", ",".join(TRAIN_TASKS),
            "--demos", "2", "--preset", "smoke", "--steps", "4", "--batch", "2", "--lr", "1e-4",
            "--schedule", "constant", "--warmup", "0", "--checkpoint-every", "1", "--val-every", "2",
            "--val-samples", "2", "--log-every", "1", "--images-every", "0", "--no-progress",
            *extra)  # fmt: skip


def metrics_without_timing(run_dir: Path) -> list[dict]:
    return [
        {k: v for k, v in r.items() if k != "steps_per_s"} for r in whole_lines(run_dir / "metrics.jsonl")
    ]


@pytest.mark.parametrize(
    ("target", "occurrence", "kept"),
    [
        # torch's writer: a RuntimeError over ENOSPC; the resumed step 3 must record step 2's validation
        ("step_000003.pt", 1, "checkpoint step 2 kept"),
        ("metrics.jsonl", 5, "checkpoint step 3 kept"),  # the step-4 record, cut mid-line
        ("last.pt", 1, "no checkpoint written yet"),  # the first copy: the re-run starts over
    ],
)
def test_train_on_a_full_disk(
    train_data, train_full, tmp_path, capsys, monkeypatch, target, occurrence, kept
):
    disk = FakeDisk(monkeypatch)
    disk.fill_during(target, occurrence)
    out = tmp_path / "part"
    line = full_disk_error(capsys, *train_args(train_data, out))
    assert disk.filled
    assert kept in line and target in line and "--resume" in line
    no_temporary_files(out)
    whole_lines(out / "metrics.jsonl")
    disk.free = None  # space freed
    code, _, err = run(capsys, *train_args(train_data, out, "--resume"))
    assert code == 0, err
    assert files(out / "checkpoints") == files(train_full / "checkpoints")
    assert metrics_without_timing(out) == metrics_without_timing(train_full)


# ------------------------------------------------------------------------------------ tvf eval
EVAL = ("eval", "--method", "oracle", "--tasks", "stack-stair,put-t", "--episodes", "3",
        "--env", "disk_fakes:ScriptedWorlds")  # fmt: skip


@pytest.mark.parametrize(
    ("target", "occurrence", "kept"),
    [("episodes.jsonl", 3, 2), ("summary.md", 1, 6), ("eval.json", 1, 0)],
)
def test_eval_on_a_full_disk(tmp_path, capsys, monkeypatch, target, occurrence, kept):
    code, _, err = run(capsys, *EVAL, "--out", str(tmp_path / "full"))
    assert code == 0, err
    disk = FakeDisk(monkeypatch)
    disk.fill_during(target, occurrence)
    out = tmp_path / "part"
    line = full_disk_error(capsys, *EVAL, "--out", str(out))
    assert disk.filled
    assert f"{kept} of 6 episodes kept in {out / 'episodes.jsonl'}" in line and target in line
    no_temporary_files(out)
    assert len(whole_lines(out / "episodes.jsonl")) == kept
    disk.free = None  # space freed
    code, _, err = run(capsys, *EVAL, "--out", str(out))
    assert code == 0, err
    assert files(out) == files(tmp_path / "full")


def test_eval_after_a_torn_line_starts_the_next_record_on_a_fresh_line(tmp_path, capsys):
    """A kill mid-write leaves half a record: the re-run notes it, runs that episode again and writes
    the log an uninterrupted run writes (the next record is not glued onto the torn one)."""
    code, _, err = run(capsys, *EVAL, "--out", str(tmp_path / "full"))
    assert code == 0, err
    log = tmp_path / "part" / "episodes.jsonl"
    log.parent.mkdir()
    shutil.copy(tmp_path / "full" / "eval.json", tmp_path / "part" / "eval.json")
    whole = (tmp_path / "full" / "episodes.jsonl").read_bytes().splitlines(keepends=True)
    log.write_bytes(b"".join(whole[:2]) + whole[2][:25])
    code, out, err = run(capsys, *EVAL, "--out", str(tmp_path / "part"))
    assert code == 0, err
    assert "resuming: 2 of 6 episodes" in out
    assert "ignored a torn last line (25 bytes" in err and "dropped a torn last line (25 bytes" in err
    assert files(tmp_path / "part") == files(tmp_path / "full")


# ------------------------------------------------------------------------------------ the CLI boundary
@pytest.mark.parametrize("wrapped", [False, True])
def test_a_full_disk_anywhere_else_is_one_line(capsys, monkeypatch, wrapped):
    """A library writing its own file (TensorBoard, a figure) on a full disk: one line, exit code 2."""
    from disk_fakes import no_space

    from tvf.cli.world import TasksCmd

    def run_on_a_full_disk(self):
        if not wrapped:
            raise no_space()
        try:
            raise no_space()
        except OSError:
            raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 704 vs 598")  # noqa: B904

    monkeypatch.setattr(TasksCmd, "run", run_on_a_full_disk)
    line = full_disk_error(capsys, "tasks")
    assert line == "tvf: error: no space left on device; free space and re-run the same command to resume"


def test_other_errors_are_not_taken_for_a_full_disk():
    assert as_disk_full(RuntimeError("unexpected pos 704 vs 598")) is None
    assert as_disk_full(OSError(13, "Permission denied")) is None
    hdf5 = RuntimeError("Can't decrement id ref count (file write failed: errno = 28, error message = 'x')")
    assert as_disk_full(hdf5, "f.h5").path == "f.h5"


# ------------------------------------------------------------------------------------ a real tmpfs
def mount_tmpfs(path: Path, size: str) -> None:
    path.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True, text=True, check=False)  # fmt: skip
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.strip() or done.returncode})")


@pytest.fixture
def tmpfs(tmp_path):
    """A folder on a small tmpfs (``tmpfs.resize(SIZE)`` frees space), unmounted afterwards."""
    if shutil.which("mount") is None:
        pytest.skip("no mount command")
    path = tmp_path / "tmpfs"

    class Mount:
        root = path

        @staticmethod
        def resize(size: str) -> None:
            subprocess.run(["mount", "-o", f"remount,size={size}", str(path)], check=True)

    yield Mount
    subprocess.run(["umount", "-l", str(path)], check=False)


def tvf(*args: str) -> subprocess.CompletedProcess:
    """The real `tvf` in a fresh process (a segfault shows as a negative return code)."""
    return subprocess.run([sys.executable, "-m", "tvf", *args], capture_output=True, text=True, check=False)


def real_error(done: subprocess.CompletedProcess) -> str:
    assert done.returncode == 2, (done.returncode, done.stderr[-3000:])
    assert "Traceback" not in done.stderr
    errors = [line for line in done.stderr.replace("\r", "\n").splitlines() if line.startswith("tvf: error:")]
    assert len(errors) == 1 and "no space left on " in errors[0], done.stderr[-3000:]
    return errors[0]


@pytest.mark.slow
def test_demos_on_a_real_full_tmpfs(tmpfs, tmp_path):
    """stack-tower episodes are about 270 kB: a 700 kB tmpfs holds two (HDF5 used to segfault here)."""
    mount_tmpfs(tmpfs.root, "700k")
    args = ("demos", "--tasks", "stack-tower", "--episodes", "4")
    line = real_error(tvf(*args, "--out", str(tmpfs.root / "d")))
    assert "2 episodes kept" in line
    no_temporary_files(tmpfs.root)
    tmpfs.resize("3m")
    assert tvf(*args, "--out", str(tmpfs.root / "d")).returncode == 0
    assert tvf(*args, "--out", str(tmp_path / "full")).returncode == 0
    assert files(tmpfs.root / "d") == files(tmp_path / "full")


@pytest.mark.slow
def test_train_and_eval_on_a_real_full_tmpfs(tmpfs, tmp_path, train_data):
    """A smoke checkpoint is about 2.4 MB: a 6 MB tmpfs holds step 1 and last.pt, not step 2; an
    evaluation's summary does not fit beside an 8 kB filler on a 16 kB tmpfs."""
    mount_tmpfs(tmpfs.root, "6m")
    args = train_args(train_data, tmpfs.root / "run")
    line = real_error(tvf(*args))
    assert "step_000002.pt" in line and "checkpoint step 1 kept" in line
    no_temporary_files(tmpfs.root)
    tmpfs.resize("20m")
    assert tvf(*args, "--resume").returncode == 0
    assert tvf(*train_args(train_data, tmp_path / "run")).returncode == 0
    assert files(tmpfs.root / "run" / "checkpoints") == files(tmp_path / "run" / "checkpoints")

    shutil.rmtree(tmpfs.root / "run")
    tmpfs.resize("16k")
    (tmpfs.root / "filler").write_bytes(bytes(8192))
    args = ("eval", "--method", "oracle", "--tasks", "stack-stair", "--episodes", "2")
    line = real_error(tvf(*args, "--out", str(tmpfs.root / "e")))
    assert "summary.json" in line and "2 of 2 episodes kept" in line
    (tmpfs.root / "filler").unlink()
    assert tvf(*args, "--out", str(tmpfs.root / "e")).returncode == 0
    assert tvf(*args, "--out", str(tmp_path / "e")).returncode == 0
    assert files(tmpfs.root / "e") == files(tmp_path / "e")
