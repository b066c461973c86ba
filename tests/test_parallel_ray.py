"""The Ray backend on a local Ray instance of 2 CPUs started here: the same results in the same order as
the process pool, byte-identical datasets and evaluation logs, and a job whose worker dies is retried."""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")
from ray import cloudpickle  # noqa: E402

import tvf.parallel  # noqa: E402 - after the skip
from tvf.cli import main  # noqa: E402
from tvf.data.generation import GenerationPlan, generate  # noqa: E402
from tvf.errors import TvfError  # noqa: E402
from tvf.evaluate.closed_loop import evaluate  # noqa: E402
from tvf.parallel import connect_ray, run_jobs  # noqa: E402
from tvf.policies import PolicySpec  # noqa: E402


@pytest.fixture(scope="module")
def local_ray():
    """One quiet local Ray instance for the module (tvf's own start-up), shut down after it."""
    if ray.is_initialized():
        ray.shutdown()
    sigterm = signal.getsignal(signal.SIGTERM)  # ray.init sets its own handler
    connect_ray(2)
    here = sys.modules[__name__]  # the jobs below travel by value: Ray's workers cannot import this file
    cloudpickle.register_pickle_by_value(here)
    yield
    cloudpickle.unregister_pickle_by_value(here)
    ray.shutdown()
    signal.signal(signal.SIGTERM, sigterm)


def staggered(x: int) -> tuple[int, int]:
    """Later jobs finish first, so the order of completion is not the order of the jobs."""
    time.sleep((6 - x % 6) / 100)
    return x, x * x


def crash_once(folder: str, x: int) -> int:
    """For ``x`` = 1, kills its worker process the first time it runs (a marker file remembers)."""
    marker = Path(folder) / f"{x}.crashed"
    if x == 1 and not marker.exists():
        marker.write_text(str(os.getpid()))
        os._exit(1)
    return x * x


def always_crash(x: int) -> int:
    os._exit(1)


def fails(x: int) -> int:
    raise TvfError(f"job {x} is bad")


def test_ray_yields_what_the_local_backend_yields_in_job_order(local_ray):
    """(The local pool's order, and its equality with one process, are tested in tests/data and
    tests/evaluate; the pool itself meets Ray in the dataset test below.)"""
    jobs = [(i,) for i in range(10)]
    local = list(run_jobs(staggered, jobs, 1, progress=False))
    assert list(run_jobs(staggered, jobs, 2, progress=False, backend="ray")) == local
    assert local == [(i, i * i) for i in range(10)]


def test_a_job_error_reaches_the_caller_unwrapped_and_is_not_retried(local_ray):
    with pytest.raises(TvfError, match="^job 1 is bad$"):
        list(run_jobs(fails, [(1,), (2,)], 2, progress=False, backend="ray"))


def test_a_worker_that_dies_loses_only_its_job_which_is_retried(local_ray, tmp_path):
    jobs = [(str(tmp_path), i) for i in range(4)]
    assert list(run_jobs(crash_once, jobs, 2, progress=False, backend="ray")) == [0, 1, 4, 9]
    assert [p.name for p in tmp_path.glob("*.crashed")] == ["1.crashed"]  # its first worker died


def test_a_worker_that_keeps_dying_is_one_clear_error(local_ray, monkeypatch):
    monkeypatch.setattr(tvf.parallel, "RAY_RETRIES", 0)  # one try: one worker start, not four
    with pytest.raises(TvfError, match="Ray worker failed 1 time .WorkerCrashedError"):
        list(run_jobs(always_crash, [(1,)], 2, progress=False, backend="ray"))


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.slow  # episodes made twice: about 15 s
def test_ray_demos_are_the_same_bytes_as_the_pools(local_ray, tmp_path):
    """A real oracle dataset (one task, two test-split episodes) from 2 pool workers and from 2 Ray workers
    (`tvf demos --backend ray`), where the Ray workers send the files' bytes back and this process writes
    them: every file is the same, the manifest (with every episode's checksums) included."""
    plan = GenerationPlan(("stack-tower",), "test", 2, tmp_path / "local")  # oracle steps only
    report = generate(plan, 2, progress=False)
    assert report.generated == 2 and not report.short
    main(["demos", "--tasks", "stack-tower", "--split", "test", "--episodes", "2", "--workers", "2",
          "--backend", "ray", "--out", str(tmp_path / "ray")])  # fmt: skip
    made = {backend: _files(tmp_path / backend / "test") for backend in ("local", "ray")}
    assert "manifest.json" in made["ray"] and len(made["ray"]) >= 3
    assert made["ray"] == made["local"]


@pytest.mark.slow  # an evaluation run twice
def test_ray_evaluation_writes_the_same_episodes_jsonl(local_ray, tmp_path):
    """The library with one process against `tvf eval --backend ray`, also with --envs-per-worker 2 (the
    instance above is reused)."""
    evaluate(PolicySpec("oracle"), ["stack-tower"], 2, 1, 1, tmp_path / "local")
    flags = ["eval", "--method", "oracle", "--tasks", "stack-tower", "--episodes", "2", "--seed-start", "1",
             "--workers", "2", "--backend", "ray"]  # fmt: skip
    main([*flags, "--out", str(tmp_path / "ray")])
    main([*flags, "--envs-per-worker", "2", "--out", str(tmp_path / "group")])
    logs = {b: ((tmp_path / b / "episodes.jsonl").read_bytes(), (tmp_path / b / "summary.json").read_bytes())
            for b in ("local", "ray", "group")}  # fmt: skip
    assert logs["ray"] == logs["local"] == logs["group"]  # one Ray task per episode, or per group of two
    assert logs["ray"][0].count(b"\n") == 2
