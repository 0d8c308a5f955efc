"""Threads for the driver's numpy stages (layer conversion, reprojection).

numpy releases the GIL inside each array operation, so a few threads that each run large
enough operations use more than one core; many small operations make the threads wait for
the GIL instead.  Measured on a 2-core machine at 1280x720: layer conversion 21.5 -> 12.3 ms,
reprojection 65 -> 46 ms with two threads.  More threads than two were not measured and
contend for the GIL, so :func:`default_threads` stops at two (a helper process that once
split the reprojection went: docs/results/history.md).
"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

#: Most threads the driver uses by default.
MAX_DEFAULT_THREADS = 2

_pools: dict[int, ThreadPoolExecutor] = {}
_lock = threading.Lock()


def default_threads() -> int:
    """Driver threads when the caller does not say: this machine's cores, at most two."""
    return max(1, min(MAX_DEFAULT_THREADS, os.cpu_count() or 1))


def executor(threads: int) -> ThreadPoolExecutor | None:
    """A shared pool of ``threads`` workers (created once per size), or None for one thread."""
    if threads <= 1:
        return None
    with _lock:
        pool = _pools.get(threads)
        if pool is None:
            pool = _pools[threads] = ThreadPoolExecutor(threads, thread_name_prefix="mcdenoise")
        return pool


def run_all(fn, args_list, threads: int) -> list:
    """``[fn(*args) for args in args_list]``, on ``threads`` workers when > 1 (results in
    order; the first exception is raised after every job has finished)."""
    pool = executor(threads)
    if pool is None or len(args_list) < 2:
        return [fn(*args) for args in args_list]
    jobs = [pool.submit(fn, *args) for args in args_list]
    errors = [j.exception() for j in jobs]
    for e in errors:
        if e is not None:
            raise e
    return [j.result() for j in jobs]
