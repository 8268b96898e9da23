"""Messages that C libraries print themselves (libpng through OpenCV, RPly through Open3D).

Such libraries write straight to the process's standard error (file descriptor 2), before and
beside gtvo's own one-line error. :func:`captured_native_stderr` sends descriptor 2 to a
temporary file for the length of one library call, so that the caller decides what is shown:
nothing when the call succeeded, or the library's words inside gtvo's one line when it failed.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from dataclasses import dataclass
from typing import Iterator


@dataclass
class NativeText:
    """What a library wrote to descriptor 2 inside :func:`captured_native_stderr` (set when it ends)."""

    text: str = ""

    def lines(self) -> list[str]:
        """The non-empty lines written, stripped."""
        return [line.strip() for line in self.text.splitlines() if line.strip()]

    def summary(self, limit: int = 160) -> str:
        """The lines joined with ``"; "`` and cut to ``limit`` characters (for a one-line error)."""
        text = "; ".join(self.lines())
        return text if len(text) <= limit else text[: limit - 3] + "..."


@contextlib.contextmanager
def captured_native_stderr() -> Iterator[NativeText]:
    """Capture what is written to file descriptor 2 during the block (C libraries included).

    Python's own ``sys.stderr`` is flushed first, so that nothing written before is captured.
    When descriptor 2 cannot be redirected (closed), the block runs without capture.
    """
    captured = NativeText()
    try:
        sys.stderr.flush()
    except (AttributeError, ValueError, OSError):
        pass
    try:
        saved = os.dup(2)
    except OSError:
        yield captured
        return
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield captured
        finally:
            try:
                sys.stderr.flush()
            except (AttributeError, ValueError, OSError):
                pass
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            captured.text = sink.read().decode("utf-8", errors="replace")
