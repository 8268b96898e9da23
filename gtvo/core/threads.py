"""The threads gtvo's compiled loops run on: one process-wide pool, sized by the configuration.

The window evaluates every host's points in each of its targets; the targets are independent, and
the compiled loops release the GIL (:func:`gtvo.core.jit.jit`), so two targets run on two cores at
once while Python prepares the next. :func:`thread_map` is ``map`` over such independent calls, in
order: the results, and all sums made from them afterwards, are those of the serial loop, bit for bit.

``set_threads(n)`` sizes the pool (``WindowConfig.threads``, set by
:class:`gtvo.odometry.VisualOdometry`); 1 runs everything in the calling thread. The pool is
process-wide: the last setting wins.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, TypeVar

from gtvo.errors import InputError

T = TypeVar("T")
R = TypeVar("R")

_threads = 1
_pool: ThreadPoolExecutor | None = None


def default_threads() -> int:
    """The cores this process may use (``os.sched_getaffinity``), at most 4."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        n = os.cpu_count() or 1
    return max(1, min(4, n))


def set_threads(n: int) -> None:
    """Run :func:`thread_map` on ``n`` threads (0: :func:`default_threads`; 1: the calling thread only)."""
    global _threads, _pool
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise InputError(f"threads must be a whole number >= 0, got {n!r}")
    n = default_threads() if n == 0 else n
    if n != _threads and _pool is not None:
        _pool.shutdown(wait=True)
        _pool = None
    _threads = n


def threads() -> int:
    """The number of threads :func:`thread_map` uses."""
    return _threads


def thread_map(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(x) for x in items]``, the calls spread over the pool's threads; results in order.
    An exception of any call is raised here (the first in order)."""
    work = list(items)
    if _threads <= 1 or len(work) < 2:
        return [fn(x) for x in work]
    global _pool
    if _pool is None:
        _pool = ThreadPoolExecutor(max_workers=_threads, thread_name_prefix="gtvo")
    return list(_pool.map(fn, work))
