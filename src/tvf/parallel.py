"""The one process pool of tvf: run many jobs in ``spawn``-ed worker processes, results in job order.

PyBullet has one client per process, so parallelism is over processes. Each worker runs ``init``
once (e.g. to install the task table it was handed) and uses one torch thread, so the workers share
the cores instead of fighting over them.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any

import torch
from tqdm import tqdm


def init_worker(init: Callable[..., Any] | None = None, init_args: tuple = (), threads: int = 1) -> None:
    """Per-process set-up: ``threads`` torch threads, then ``init(*init_args)``."""
    os.environ.setdefault("OMP_NUM_THREADS", str(threads))
    torch.set_num_threads(threads)
    if init is not None:
        init(*init_args)


def make_pool(workers: int, init: Callable[..., Any] | None = None, init_args: tuple = ()):
    """A spawn-context pool whose workers ran :func:`init_worker` (one torch thread each)."""
    ctx = get_context("spawn")
    return ProcessPoolExecutor(
        workers, mp_context=ctx, initializer=init_worker, initargs=(init, init_args, 1)
    )


def run_jobs(
    fn: Callable, jobs: Sequence[tuple], workers: int = 1, desc: str = "episodes",
    init: Callable[..., Any] | None = None, init_args: tuple = (), progress: bool = True,
) -> Iterator:  # fmt: skip
    """Yield ``fn(*job)`` for each job, in order, using ``workers`` processes (1 = this process)."""
    bar = tqdm(total=len(jobs), desc=desc, unit="ep", disable=not progress, dynamic_ncols=True)
    try:
        if workers <= 1:
            init_worker(init, init_args, threads=max(1, os.cpu_count() or 1))
            for job in jobs:
                yield fn(*job)
                bar.update()
            return
        with make_pool(workers, init, init_args) as pool:
            futures = [pool.submit(fn, *job) for job in jobs]
            for fut in futures:
                yield fut.result()
                bar.update()
    finally:
        bar.close()
