"""The threads a process lends to its compiled kernels: one by default (none of its own), more only
where a process asks (the parallel window's worker, ``window.worker_threads``; docs/window.md,
"Kernel threads in the worker").

gtvo's compiled loops release the GIL (:func:`gtvo.core.jit.jit`), so independent kernel calls can
run on several cores from threads. :func:`map_independent` runs a list of calls
that share no state (each only returns its own result) on this process's kernel threads: the
calling thread and ``threads - 1`` pool threads take the next call until none is left, and the
results come back in the calls' order. Which thread runs which call depends on timing, the results do not:
each call's arithmetic is the same on any thread, and nothing is summed across calls here (no
reduction whose order could vary). With one thread (the default) it is the plain loop.
"""

from __future__ import annotations

import itertools
from concurrent.futures import ThreadPoolExecutor, wait
import threading
import time
from typing import Callable, Sequence, TypeVar

T = TypeVar("T")

_threads = 1
_pool: ThreadPoolExecutor | None = None
_inside = threading.local()  # .active: this thread is running a map_independent's calls
_pool_cpu = [0.0]  # CPU seconds the pool threads spent in calls (under _pool_cpu_lock)
_pool_cpu_lock = threading.Lock()


def set_kernel_threads(threads: int) -> None:
    """Run :func:`map_independent` on ``threads`` threads (the caller's and ``threads - 1`` pool threads,
    started now; 1: no pool). Meant for a process's start (the window's worker); the pool's threads
    are daemon-like: they end with the process.

    Raises:
        ValueError: ``threads`` is not an integer >= 1.
    """
    global _threads, _pool
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"kernel threads must be an integer >= 1, got {threads!r}")
    if _pool is not None:
        _pool.shutdown(wait=True)
    _threads = threads
    _pool = ThreadPoolExecutor(threads - 1, thread_name_prefix="gtvo-kernel") if threads > 1 else None


def pool_cpu_seconds() -> float:
    """CPU seconds the pool threads (not the calling threads) have spent in :func:`map_independent`'s
    calls in this process: the work the other cores took off the caller (the window's worker
    reports it, docs/window.md)."""
    with _pool_cpu_lock:
        return _pool_cpu[0]


def kernel_threads() -> int:
    """The number of threads :func:`map_independent` runs on in this process (1 unless set)."""
    return _threads


def map_independent(calls: Sequence[Callable[[], T]]) -> list[T]:
    """``[call() for call in calls]``, on the process's kernel threads (module docstring): the calls
    must not share mutable state. From inside such a call (a nested map), or with one thread, the
    plain loop. An exception of a call is raised once every thread has stopped (the calling
    thread's own first, else a pool thread's)."""
    pool = _pool
    count = len(calls)
    if pool is None or count < 2 or getattr(_inside, "active", False):
        return [call() for call in calls]
    out: list = [None] * count
    indices = itertools.count()  # next() is atomic under the GIL: every index is taken once

    def drain() -> None:
        _inside.active = True
        try:
            for k in iter(indices.__next__, None):
                if k >= count:
                    return
                out[k] = calls[k]()
        finally:
            _inside.active = False

    def helper() -> None:
        cpu = time.thread_time()
        try:
            drain()
        finally:
            with _pool_cpu_lock:
                _pool_cpu[0] += time.thread_time() - cpu

    helpers = [pool.submit(helper) for _ in range(min(_threads, count) - 1)]
    try:
        drain()
    finally:
        wait(helpers)
    for h in helpers:
        h.result()  # re-raises a helper's exception
    return out
