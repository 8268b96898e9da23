"""Ctrl-C that a library swallowed still stops the run.

A SIGINT raises :class:`KeyboardInterrupt` wherever Python happens to be; when that is inside a
third-party import or callback that catches broad exceptions (measured: matplotlib's optional
``mpl_toolkits.mplot3d`` import turns it into a warning and goes on), the interrupt is lost and the
run would finish as if nothing happened. The ``gtvo`` command therefore installs
:func:`note_interrupt` as its SIGINT handler: it records the interrupt before raising it, and the
run checks :func:`raise_if_interrupted` between frames and before writing outputs, and the CLI
once more when the command returns. A library user's own handler is left alone (nothing is
installed on import).

Once a command's outputs are in place (:func:`outputs_in_place`), the command has succeeded:
a Ctrl-C while it prints its summary or exits no longer turns that into exit code 130.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from types import FrameType
from typing import Iterator

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


def outputs_in_place() -> None:
    """Say that the command's work is done and its outputs are in place: SIGINT is ignored from
    here on (in the main thread; the command only prints and exits), and an interrupt noted so
    far is forgotten (it came after the last check before the outputs were committed)."""
    global _interrupted
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    _interrupted = False


@contextlib.contextmanager
def interrupts_held() -> Iterator[None]:
    """Hold back SIGINT during the block: blocked in this thread (processes started here inherit
    the mask) and, should another thread take it, only recorded; it is raised again once the
    block is over. Outside the main thread, or under a handler not set from Python: no change."""
    handler = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or handler is None:
        yield
        return
    caught: list[int] = []
    signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        signal.signal(signal.SIGINT, handler)
    if caught:
        signal.raise_signal(signal.SIGINT)  # to the handler that was there (Ctrl-C: KeyboardInterrupt)
