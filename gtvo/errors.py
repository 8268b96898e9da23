"""Errors that gtvo raises for bad input.

Every problem with what a user hands us (a missing file, a corrupt image, a malformed
calibration line, NaN, an empty graph, degenerate motion) is raised as :class:`InputError`
with a one-line message that names the file or the value. The CLI turns it into that one
line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path


class GtvoError(Exception):
    """Base class of gtvo's own errors."""


class InputError(GtvoError, ValueError):
    """Bad input: the message is one line naming the file (and line) or the value."""

    def __init__(self, message: str, path: str | Path | None = None, line: int | None = None):
        where = ""
        if path is not None:
            where = f"{path}"
            if line is not None:
                where += f":{line}"
            where += ": "
        super().__init__(f"{where}{message}")
        self.path = None if path is None else Path(path)
        self.line = line


class DependencyError(GtvoError, ImportError):
    """An optional dependency (or the system library it needs) is missing."""


class TrackingFailure(GtvoError):
    """Tracking could not produce a trustworthy pose (too few points, diverging cost...)."""


def not_a_file(path: str | Path, what: str = "file", line: int | None = None) -> InputError:
    """The :class:`InputError` for ``path`` where a file was expected and is not: ``"is a folder,
    not a <what>"`` when it is a folder, else ``"<what> not found"``."""
    if Path(path).is_dir():
        return InputError(f"is a folder, not a {what}", path, line)
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return InputError(f"{what} is a symbolic link loop", path, line)
        if os.path.islink(path):
            return InputError(f"{what} is a broken symbolic link (to {os.readlink(path)})", path, line)
    return InputError(f"{what} not found", path, line)


def show(value: object) -> str:
    """``repr`` of a value for a message, numpy scalars and arrays (also inside a tuple or list)
    as plain Python numbers and lists: ``1.5``, not ``np.float64(1.5)``."""
    def plain(v: object) -> object:
        if hasattr(v, "tolist"):
            return v.tolist()
        if isinstance(v, (tuple, list)):
            return type(v)(plain(x) for x in v)
        return v
    return repr(plain(value))


def caused_by_interrupt(exc: BaseException) -> bool:
    """True when a :class:`KeyboardInterrupt` is in ``exc``'s chain (``__cause__`` / ``__context__``).

    Ctrl-C that lands inside compiled code surfaces as another error with the interrupt as its
    context: ``SystemError: CPUDispatcher(...) returned a result with an exception set`` when a
    numba function returns, ``ImportError: initialization failed`` when an extension module
    (open3d, gtsam) is being imported. Those are interrupts, not crashes or missing packages.
    """
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False
