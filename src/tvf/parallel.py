"""The one process pool of tvf: run many jobs in ``spawn``-ed worker processes, results in job order.

PyBullet has one client per process, so parallelism is over processes. Jobs carry everything they need
as values (tasks, policy specs, environment factories); each worker uses one torch thread, so the
workers share the cores instead of fighting over them.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

import torch
from tqdm import tqdm


def init_worker(threads: int = 1) -> None:
    """Per-process set-up: ``threads`` torch threads."""
    os.environ.setdefault("OMP_NUM_THREADS", str(threads))
    torch.set_num_threads(threads)


def make_pool(workers: int) -> ProcessPoolExecutor:
    """A spawn-context pool whose workers use one torch thread each."""
    return ProcessPoolExecutor(
        workers, mp_context=get_context("spawn"), initializer=init_worker, initargs=(1,)
    )


def run_jobs(
    fn: Callable, jobs: Sequence[tuple], workers: int = 1, desc: str = "episodes", progress: bool = True
) -> Iterator:
    """Yield ``fn(*job)`` for each job, in order, using ``workers`` processes (1 = this process)."""
    bar = tqdm(total=len(jobs), desc=desc, unit="ep", disable=not progress, dynamic_ncols=True)
    try:
        if workers <= 1:
            init_worker(threads=max(1, os.cpu_count() or 1))
            for job in jobs:
                yield fn(*job)
                bar.update()
            return
        with make_pool(workers) as pool:
            futures = [pool.submit(fn, *job) for job in jobs]
            try:
                for fut in futures:
                    yield fut.result()
                    bar.update()
            finally:  # a caller that stops early (an error, a full disk) does not wait for the rest
                for fut in futures:
                    fut.cancel()
    finally:
        bar.close()
