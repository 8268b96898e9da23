"""Errors that gtvo raises for bad input.

Every problem with what a user hands us (a missing file, a corrupt image, a malformed
calibration line, NaN, an empty graph, degenerate motion) is raised as :class:`InputError`
with a one-line message that names the file or the value. The CLI turns it into that one
line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

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
