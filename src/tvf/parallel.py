"""The one scheduler of tvf: run many jobs in worker processes, results in job order, on one of two backends.

PyBullet has one client per process, so parallelism is over processes. Jobs carry everything they need
as values (tasks, policy specs, environment factories); each worker uses one torch thread, so the
workers share the cores instead of fighting over them.

Backends (``--backend``): ``local``, a ``spawn`` process pool on this host, and ``ray``, every job a Ray
task (``num_cpus=1``) on a local Ray instance of ``workers`` CPUs or, with ``address``, on a running
cluster. Either way the caller receives the results in job order, so what it writes does not depend on
the backend or on ``workers``. A Ray task whose worker dies is run again (``RAY_RETRIES`` times); a job
that raises is not (its error reaches the caller, as with the pool). Ray is imported only when chosen.

A SIGTERM to the parent while a pool runs raises :class:`~tvf.errors.Terminated` there, so the pool is
shut down and its workers ended; a local worker also exits by itself when its parent is gone.
"""

from __future__ import annotations

import os
import signal
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import (
    FIRST_COMPLETED,
    CancelledError,
    Future,
    InvalidStateError,
    ProcessPoolExecutor,
    wait,
)
from contextlib import contextmanager, suppress
from multiprocessing import get_context
from typing import Any

from tqdm import tqdm

from tvf.errors import Terminated, TvfError

BACKENDS = ("local", "ray")
RAY_RETRIES = 3
"""Times a Ray task is run again when its worker process dies (system failures only)."""
RAY_INSTALL = "pip install 'tvf[ray]'"


def init_worker(threads: int = 1, parent: int | None = None) -> None:
    """Per-process set-up: ``threads`` torch threads; with ``parent``, exit when that process is gone."""
    import torch  # here, not at import: `tvf.parallel` is cheap to import (the CLI, a Ray worker's start)

    os.environ.setdefault("OMP_NUM_THREADS", str(threads))
    torch.set_num_threads(threads)
    if parent is not None:
        threading.Thread(target=_exit_with_parent, args=(parent,), daemon=True).start()


def lone_process_threads() -> int:
    """Torch threads of a job run in this process (``--workers 1``): ``OMP_NUM_THREADS`` when it is set
    (several such jobs sharing the cores each want 1), else every core."""
    value = os.environ.get("OMP_NUM_THREADS", "")
    return int(value) if value.isdigit() and int(value) > 0 else max(1, os.cpu_count() or 1)


def _exit_with_parent(parent: int, every: float = 0.5) -> None:
    """Watch the parent: a worker whose parent died (killed, even with SIGKILL) is reparented; it exits."""
    while os.getppid() == parent:
        time.sleep(every)
    os._exit(1)


class WorkerPool(ProcessPoolExecutor):
    """A spawn-context pool whose workers use one torch thread each and exit with their parent;
    ``shutdown(cancel_futures=True)`` also ends the workers still running a job (its result is unwanted)."""

    def __init__(self, workers: int) -> None:
        super().__init__(workers, mp_context=get_context("spawn"), initializer=init_worker,
                         initargs=(1, os.getpid()))  # fmt: skip

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        if not cancel_futures:
            super().shutdown(wait)
            return
        processes = list((self._processes or {}).values())
        super().shutdown(wait=False, cancel_futures=True)
        for p in processes:
            if p.is_alive():
                p.terminate()
        for p in processes:
            p.join(10)
        super().shutdown(wait)


class RayPool:
    """The executor interface (``submit`` -> :class:`~concurrent.futures.Future`, ``shutdown``) over Ray
    tasks. A job's own exception reaches the future unwrapped; a worker that died more than
    ``RAY_RETRIES`` times, or another system failure, is a :class:`TvfError`."""

    def __init__(self, workers: int, address: str | None = None) -> None:
        self.ray = connect_ray(workers, address)
        self.task = self.ray.remote(_ray_call).options(num_cpus=1, max_retries=RAY_RETRIES,
                                                        retry_exceptions=False)  # fmt: skip
        self.futures: set[Future] = set()
        self.lock = threading.Lock()

    def submit(self, fn: Callable, *args) -> Future:
        ref = self.task.remote(fn, args)
        outer = _RayFuture(self.ray, ref)
        with self.lock:
            self.futures.add(outer)
        ref.future().add_done_callback(lambda inner: self._settle(outer, inner))
        return outer

    def _settle(self, outer: Future, inner: Future) -> None:
        """Hand the task's outcome to ``outer`` (called in a Ray thread; ``outer`` may be cancelled)."""
        with self.lock:
            self.futures.discard(outer)
        try:
            result, error = inner.result(), None
        except CancelledError:
            outer.cancel()
            return
        except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
            result, error = None, _ray_error(self.ray, exc)
        with suppress(InvalidStateError):  # cancelled meanwhile: nobody waits for it
            if error is None:
                outer.set_result(result)
            else:
                outer.set_exception(error)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Cancel what has not finished when asked; the Ray instance stays up for the next pool."""
        if cancel_futures:
            with self.lock:
                unfinished = list(self.futures)
            for fut in unfinished:
                fut.cancel()


class _RayFuture(Future):
    def __init__(self, ray: Any, ref: Any) -> None:
        super().__init__()
        self.ray, self.ref = ray, ref

    def cancel(self) -> bool:
        if not self.done():
            with suppress(Exception):  # a task that just finished cannot be cancelled
                self.ray.cancel(self.ref, force=True)
        return super().cancel()


def _ray_call(fn: Callable, args: tuple) -> Any:
    """A Ray task: ``fn(*args)`` with one torch thread."""
    init_worker(1)
    return fn(*args)


def _ray_error(ray: Any, exc: BaseException) -> BaseException:
    """The job's own exception for a task that raised; a one-line TvfError for a system failure."""
    if isinstance(exc, ray.exceptions.RayTaskError) and not isinstance(exc.cause, ray.exceptions.RayError):
        cause = exc.cause
        return cause if isinstance(cause, BaseException) else TvfError(f"a Ray task failed: {exc}")
    if isinstance(exc, ray.exceptions.RayTaskError):
        exc = exc.cause  # a system failure inside the task (its arguments could not be read, ...)
    if isinstance(exc, ray.exceptions.RayError):
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        tries = RAY_RETRIES + 1
        return TvfError(
            f"a job's Ray worker failed {tries} time{'s' * (tries > 1)} ({type(exc).__name__}: {first}); "
            "see the worker logs under /tmp/ray/session_latest/logs on its node, then re-run to resume"
        )
    return exc


def import_ray() -> Any:
    """The ``ray`` module, or a one-line TvfError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise TvfError(f"--backend ray needs Ray: {RAY_INSTALL}") from None
    return ray


def connect_ray(workers: int, address: str | None = None) -> Any:
    """Ray, initialised once per process: a quiet local instance with ``workers`` CPUs, or a connection to
    the cluster at ``address`` (``HOST:6379`` or ``auto``); an instance already started is reused."""
    ray = import_ray()
    if ray.is_initialized():
        return ray
    if address and address != "auto":
        check_reachable(address)
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    os.environ.setdefault("RAY_worker_niceness", "0")  # Ray's default, +15, starves them on a busy host
    quiet = {"include_dashboard": False, "log_to_driver": False, "logging_level": "ERROR"}
    try:
        if address:
            ray.init(address=address, **quiet)
        else:
            ray.init(address="local", num_cpus=workers, **quiet)
    except (ConnectionError, ValueError, RuntimeError) as exc:
        where = f"the Ray cluster at {address}" if address else "a local Ray instance"
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        hint = "; is `ray start --head` running there?" if address else ""
        raise TvfError(f"could not start or reach {where}: {first}{hint}") from None
    return ray


def check_reachable(address: str, timeout: float = 5.0) -> None:
    """A one-line TvfError when nothing listens at ``HOST:PORT`` (Ray itself retries for minutes)."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise TvfError(
            f"--address must be HOST:PORT (the head node's `ray start --head` port), got {address!r}"
        )
    try:
        socket.create_connection((host, int(port)), timeout).close()
    except OSError as exc:
        raise TvfError(
            f"cannot reach the Ray cluster at {address} ({exc.strerror or exc}); is `ray start --head` "
            "running there, and is the port open?"
        ) from None


def check_backend(backend: str, address: str | None = None) -> None:
    """Refuse an unknown backend, and an address without the Ray backend."""
    if backend not in BACKENDS:
        raise TvfError(f"--backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if address and backend != "ray":
        raise TvfError("--address is the Ray cluster to use: pass it with --backend ray")


def make_pool(workers: int, backend: str = "local", address: str | None = None) -> WorkerPool | RayPool:
    """The pool of ``backend``: ``workers`` spawned processes, or Ray tasks (see the module docstring)."""
    check_backend(backend, address)
    if backend == "ray":
        return RayPool(workers, address)
    return WorkerPool(workers)


def _raise_terminated(signum: int, frame: Any) -> None:
    raise Terminated(f"terminated by signal {signum}")


@contextmanager
def sigterm_raises() -> Iterator[None]:
    """While inside, SIGTERM raises :class:`~tvf.errors.Terminated` in the main thread (so ``finally``
    blocks shut pools down) instead of killing the process at once. A handler set by someone else, or a
    call from another thread, is left alone."""
    if threading.current_thread() is not threading.main_thread() or (
        signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL
    ):
        yield
        return
    signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        if signal.getsignal(signal.SIGTERM) is _raise_terminated:  # not one that Ray set meanwhile
            signal.signal(signal.SIGTERM, signal.SIG_DFL)


def run_jobs(
    fn: Callable, jobs: Sequence[tuple], workers: int = 1, desc: str = "episodes", progress: bool = True,
    backend: str = "local", address: str | None = None,
) -> Iterator:  # fmt: skip
    """Yield ``fn(*job)`` for each job, in order, using ``workers`` processes (1 with the local backend:
    this process) or, with ``backend="ray"``, at most ``workers`` Ray tasks at once."""
    check_backend(backend, address)
    bar = tqdm(total=len(jobs), desc=desc, unit="ep", disable=not progress, dynamic_ncols=True)
    try:
        if workers <= 1 and backend == "local":
            init_worker(threads=lone_process_threads())
            for job in jobs:
                yield fn(*job)
                bar.update()
            return
        with sigterm_raises():
            pool = make_pool(workers, backend, address)
            finished = False
            try:
                window = workers if backend == "ray" else len(jobs)
                for result in in_order(pool, fn, jobs, window):
                    yield result
                    bar.update()
                finished = True
            finally:  # a caller that stops early (an error, a full disk) does not wait for the rest
                pool.shutdown(cancel_futures=not finished)
    finally:
        bar.close()


def in_order(pool: Any, fn: Callable, jobs: Sequence[tuple], window: int) -> Iterator:
    """Yield ``fn(*job)`` in job order while at most ``window`` submitted jobs are unfinished."""
    todo, submitted = deque(jobs), deque()
    while todo or submitted:
        while todo and (len(submitted) < window or sum(not f.done() for f in submitted) < max(1, window)):
            submitted.append(pool.submit(fn, *todo.popleft()))
        if not submitted[0].done():
            wait([f for f in submitted if not f.done()], return_when=FIRST_COMPLETED)
            continue
        yield submitted.popleft().result()
