"""The numba decorator of gtvo's compiled loops (``factors._compiled``, ``gtvo.frontend._compiled``).

Compiled on first use and cached on disk (``__pycache__`` beside the module, or numba's user cache
directory when that is not writable; with neither, e.g. a read-only install without a home
directory, :func:`jit` compiles in every process instead of failing at import).
"""

from __future__ import annotations

from typing import Callable

import numba


def jit(fn: Callable) -> Callable:
    """``numba.njit`` with an on-disk cache when numba finds a writable place for one. The compiled
    loop releases the GIL (``nogil``): a caller's other threads run while it does."""
    try:
        return numba.njit(cache=True, nogil=True)(fn)
    except RuntimeError:  # "cannot cache function ...: no locator available"
        return numba.njit(cache=False, nogil=True)(fn)
