"""The scheduler without Ray: job order, the backend flags, Ray missing, and a SIGTERMed parent whose pool
workers must not outlive it."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

import tvf.parallel
from tvf.errors import Terminated, TvfError
from tvf.parallel import check_backend, import_ray, in_order, run_jobs, sigterm_raises


def square(x: int) -> int:
    return x * x


class Gauge:
    """Counts the jobs running at once (threads)."""

    def __init__(self) -> None:
        self.lock, self.now, self.most = threading.Lock(), 0, 0

    def job(self, x: int) -> int:
        with self.lock:
            self.now += 1
            self.most = max(self.most, self.now)
        time.sleep((5 - x % 5) / 200)  # later jobs finish first
        with self.lock:
            self.now -= 1
        return x * x


def test_in_order_keeps_job_order_and_the_window():
    gauge = Gauge()
    with ThreadPoolExecutor(6) as pool:
        out = list(in_order(pool, gauge.job, [(i,) for i in range(12)], window=2))
    assert out == [i * i for i in range(12)]
    assert gauge.most == 2  # two at once, never a third


def test_unknown_backend_and_address_without_ray_are_one_line_errors():
    with pytest.raises(TvfError, match="--backend must be one of local, ray"):
        check_backend("dask")
    with pytest.raises(TvfError, match="pass it with --backend ray"):
        check_backend("local", "head:6379")
    with pytest.raises(TvfError, match="--backend must be one of"):
        list(run_jobs(square, [(1,)], backend="spark", progress=False))


def test_missing_ray_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now raises ImportError
    with pytest.raises(TvfError, match=r"pip install 'tvf\[ray\]'"):
        import_ray()
    with pytest.raises(TvfError, match=r"pip install 'tvf\[ray\]'"):
        list(run_jobs(square, [(1,), (2,)], 2, backend="ray", progress=False))


def test_the_cli_refuses_an_address_without_ray(tmp_path, capsys):
    from tvf.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["demos", "--tasks", "stack-tower", "--episodes", "1", "--address", "head:6379",
              "--out", str(tmp_path)])  # fmt: skip
    assert exit_.value.code == 2
    assert "pass it with --backend ray" in capsys.readouterr().err


def test_sigterm_raises_only_while_inside_and_restores_the_default():
    before = signal.signal(signal.SIGTERM, signal.SIG_DFL)  # as in a fresh process (Ray sets its own)
    try:
        with pytest.raises(Terminated), sigterm_raises():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler runs at the next bytecode; never reached
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    finally:
        signal.signal(signal.SIGTERM, before)


PARENT = textwrap.dedent(
    """
    import os, sys, time
    from pathlib import Path

    def sleeper(folder, i):
        Path(folder, f"{i}.pid").write_text(str(os.getpid()))
        time.sleep(120)
        return i

    if __name__ == "__main__":
        from tvf.parallel import run_jobs
        list(run_jobs(sleeper, [(sys.argv[1], i) for i in range(4)], 2, progress=False))
    """
)


def _children_alive(pids: list[int], within: float) -> list[int]:
    deadline = time.monotonic() + within
    alive = pids
    while alive and time.monotonic() < deadline:
        alive = [p for p in alive if _running(p)]
        time.sleep(0.2)
    return alive


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    return not (stat.exists() and stat.read_text().split(")")[-1].split()[0] == "Z")  # a zombie is gone


def _start_parent(tmp_path: Path) -> tuple[subprocess.Popen, list[int]]:
    script = tmp_path / "parent.py"
    script.write_text(PARENT)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(tvf.parallel.__file__).parents[1]),
                                                        os.environ.get("PYTHONPATH", "")])}  # fmt: skip
    proc = subprocess.Popen([sys.executable, str(script), str(tmp_path)], env=env, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while len(list(tmp_path.glob("*.pid"))) < 2:  # both workers are running a job
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() < deadline, "the pool's workers never started"
        time.sleep(0.2)
    return proc, [int(p.read_text()) for p in tmp_path.glob("*.pid")]


@pytest.mark.parametrize(
    "sig", [signal.SIGTERM, pytest.param(signal.SIGKILL, marks=pytest.mark.slow)], ids=["sigterm", "sigkill"]
)
def test_a_killed_parent_leaves_no_pool_workers(tmp_path, sig):
    """SIGTERM: the parent ends its pool on the way out (exit code 143 through the interrupt); SIGKILL:
    the workers notice that their parent is gone and exit by themselves."""
    proc, workers = _start_parent(tmp_path)
    proc.send_signal(sig)
    proc.wait(60)
    assert _children_alive(workers, within=15) == []
    assert len(list(tmp_path.glob("*.pid"))) == 2  # the queued jobs were cancelled, never started
    if sig == signal.SIGTERM:
        err = proc.stderr.read().decode()
        assert "tvf.errors.Terminated: terminated by signal 15" in err  # the interrupt, raised in the parent
        assert "BrokenProcessPool" not in err


def test_the_experiment_hands_its_backend_to_the_data_and_eval_stages(tmp_path, monkeypatch):
    from tvf.data.generation import GenerationReport
    from tvf.experiment import pipeline
    from tvf.experiment.config import ExperimentConfig

    seen = []
    monkeypatch.setattr(pipeline, "generate", lambda plan, workers, tasks=None, **where: (
        seen.append(("data", workers, where)) or GenerationReport(plan.folder)))  # fmt: skip
    monkeypatch.setattr(pipeline, "evaluate", lambda *args, **where: seen.append(("eval", args[4], where)))
    cfg = ExperimentConfig(out=tmp_path, workers=3, backend="ray", address="head:6379", methods="oracle",
                           tasks="stack-tower", train_tasks="stack-tower")  # fmt: skip
    pipeline.stage_data(cfg)
    pipeline.stage_eval(cfg)
    assert [(stage, workers) for stage, workers, _ in seen] == [("data", 3), ("data", 3), ("eval", 3)]
    for _, _, kwargs in seen:
        assert kwargs["backend"] == "ray" and kwargs["address"] == "head:6379"
    from tvf.experiment.sweep import shared_settings

    assert "backend" not in shared_settings(cfg) and "address" not in shared_settings(cfg)  # not recorded


def test_a_terminated_command_says_interrupted_and_exits_143(monkeypatch, capsys):
    from tvf.cli import main
    from tvf.cli.data import DemosCmd

    def terminated(self):
        raise Terminated("terminated by signal 15")

    monkeypatch.setattr(DemosCmd, "run", terminated)
    with pytest.raises(SystemExit) as exit_:
        main(["demos", "--tasks", "stack-tower"])
    assert exit_.value.code == 143
    assert "interrupted; finished work is kept" in capsys.readouterr().err


def test_an_unreachable_or_malformed_cluster_address_is_one_line_at_once():
    from tvf.parallel import check_reachable

    with socket.socket() as s:  # a port that was free a moment ago: nothing listens there
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    start = time.monotonic()
    with pytest.raises(TvfError, match=f"cannot reach the Ray cluster at 127.0.0.1:{port}"):
        check_reachable(f"127.0.0.1:{port}")
    assert time.monotonic() - start < 5
    with pytest.raises(TvfError, match="--address must be HOST:PORT"):
        check_reachable("head-node")


def test_a_job_in_this_process_takes_its_threads_from_omp_num_threads(monkeypatch):
    from tvf.parallel import lone_process_threads

    monkeypatch.setenv("OMP_NUM_THREADS", "1")  # two such jobs sharing two cores: one thread each
    assert lone_process_threads() == 1
    for unset in ("", "0", "many"):
        monkeypatch.setenv("OMP_NUM_THREADS", unset)
        assert lone_process_threads() == max(1, os.cpu_count() or 1)
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert lone_process_threads() == max(1, os.cpu_count() or 1)
