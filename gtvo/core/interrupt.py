"""Ctrl-C that a library swallowed still stops the run.

A SIGINT raises :class:`KeyboardInterrupt` wherever Python happens to be; when that is inside a
third-party import or callback that catches broad exceptions (measured: matplotlib's optional
``mpl_toolkits.mplot3d`` import turns it into a warning and goes on), the interrupt is lost and the
run would finish as if nothing happened. The ``gtvo`` command therefore installs
:func:`note_interrupt` as its SIGINT handler: it records the interrupt before raising it, and the
run checks :func:`raise_if_interrupted` between frames and before writing outputs, and the CLI
once more when the command returns. A library user's own handler is left alone (nothing is
installed on import).
"""

from __future__ import annotations

import signal
from types import FrameType

_interrupted = False


def note_interrupt(signum: int, frame: FrameType | None) -> None:
    """SIGINT handler: remember the interrupt, then raise :class:`KeyboardInterrupt` as Python does."""
    global _interrupted
    _interrupted = True
    signal.default_int_handler(signum, frame)


def interrupt_requested() -> bool:
    """True once :func:`note_interrupt` has seen a SIGINT in this process."""
    return _interrupted


def raise_if_interrupted() -> None:
    """Raise :class:`KeyboardInterrupt` if a SIGINT was seen, even one that a library swallowed."""
    if _interrupted:
        raise KeyboardInterrupt
