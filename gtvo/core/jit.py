"""The numba decorator of gtvo's compiled loops (``factors._compiled``, ``gtvo.frontend._compiled``).

Compiled on first use and cached on disk (``__pycache__`` beside the module, or numba's user cache
directory when that is not writable: ``NUMBA_CACHE_DIR``, else ``~/.cache/numba``; with neither, e.g. a
read-only install without a home directory, :func:`jit` compiles in every process instead of failing
at import). The first run after an install compiles every kernel (tens of seconds);
:func:`announce_compilation` says so before it starts and counts the kernels as they are compiled.
"""

from __future__ import annotations

import sys
import time
from typing import Any, Callable, TextIO

import numba
import numba.core.event

#: Every kernel :func:`jit` made, in the order their modules were imported.
KERNELS: list[Any] = []
#: CPU seconds one kernel's first compilation takes, measured over gtvo's kernels on the 2-core
#: reference machine (docs/benchmarks.md, "Start-up and outputs"): for the announced estimate.
COMPILE_SECONDS_PER_KERNEL = 1.5
#: The count of compiled kernels is printed at most this often (seconds), and after the last.
PROGRESS_EVERY_S = 10.0
#: Fewer kernels than this to compile is not announced (a few seconds: e.g. the one kernel of a mode
#: the earlier runs did not use); an install's first run has all of them to compile.
MIN_ANNOUNCED = 4


def jit(fn: Callable) -> Callable:
    """``numba.njit`` with an on-disk cache when numba finds a writable place for one. The compiled
    loop releases the GIL (``nogil``): a caller's other threads run while it does."""
    try:
        kernel = numba.njit(cache=True, nogil=True)(fn)
    except RuntimeError:  # "cannot cache function ...: no locator available"
        kernel = numba.njit(cache=False, nogil=True)(fn)
    KERNELS.append(kernel)
    return kernel


def jit_inline(fn: Callable) -> Callable:
    """``numba.njit`` for a small helper of compiled loops, inlined into each kernel that calls it
    (numba's ``inline="always"``: its locals stay the caller's registers). It is compiled as part of
    its callers and cached with them, so it is not one of :data:`KERNELS`."""
    return numba.njit(inline="always", nogil=True)(fn)


def has_cached_code(kernel: Any) -> bool:
    """Whether ``kernel`` (a :func:`jit` dispatcher) has compiled code in its disk cache for this numba
    and this source file (numba's index of the kernel: missing or stale means it compiles)."""
    cache_file = getattr(getattr(kernel, "_cache", None), "_cache_file", None)  # none: no disk cache at all
    if cache_file is None:
        return False
    try:
        return bool(cache_file._load_index())
    except Exception:  # noqa: BLE001 - an unreadable index is a compilation
        return False


def cache_folder(kernel: Any) -> str | None:
    """The folder of ``kernel``'s disk cache, None when it has none (it compiles in every process)."""
    return getattr(getattr(kernel, "_cache", None), "_cache_path", None)


def announce_compilation(stream: TextIO | None = None) -> int:
    """Say on ``stream`` (default stderr) that the kernels not in the disk cache will be compiled, about
    how long that takes and where they will be cached, in one line; then count them as numba compiles
    them (a line every :data:`PROGRESS_EVERY_S` seconds and after the last). Call it after the kernels'
    modules are imported and before they run. Nothing is said when fewer than :data:`MIN_ANNOUNCED`
    kernels have no cached code (a run may not use them all: a mode's own kernel stays uncompiled).

    Returns:
        The number of kernels without cached code, announced or not.
    """
    out = stream if stream is not None else sys.stderr
    todo = {id(k) for k in KERNELS if not has_cached_code(k)}
    if len(todo) < MIN_ANNOUNCED:
        return len(todo)
    folders = {cache_folder(k) for k in KERNELS if id(k) in todo}
    where = ("no writable cache folder: they compile in every run (set NUMBA_CACHE_DIR to a writable folder)"
             if folders == {None} else "cached for later runs in " + ", ".join(sorted(str(f) for f in folders if f)))
    estimate = len(todo) * COMPILE_SECONDS_PER_KERNEL
    print(f"gtvo: compiling {len(todo)} of {len(KERNELS)} compiled kernels (numba) on first use, about "
          f"{estimate:.0f} s of CPU once; {where}", file=out, flush=True)
    numba.core.event.register("numba:compile", _CompileCounter(todo, out))
    return len(todo)


class _CompileCounter(numba.core.event.Listener):
    """Counts the announced kernels as numba finishes compiling them; unregisters itself after the last."""

    def __init__(self, todo: set[int], out: TextIO) -> None:
        self.todo, self.out, self.done = set(todo), out, 0
        self.total, self.t0, self.shown = len(todo), time.perf_counter(), time.perf_counter()

    def on_start(self, event: numba.core.event.Event) -> None:
        pass

    def on_end(self, event: numba.core.event.Event) -> None:
        kernel = (event.data or {}).get("dispatcher")
        if kernel is None or id(kernel) not in self.todo:
            return
        self.todo.discard(id(kernel))
        self.done += 1
        now, last = time.perf_counter(), not self.todo
        line = f"gtvo: compiled {self.done}/{self.total} kernels ({now - self.t0:.0f} s)"
        try:
            if last or now - self.shown >= PROGRESS_EVERY_S:
                print(line, file=self.out, flush=True)
                self.shown = now
        except (OSError, ValueError):  # noqa: S110 - a closed stream: the count is only information
            pass
        if last:
            numba.core.event.unregister("numba:compile", self)
