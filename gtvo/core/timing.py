"""Where a frame's time goes: wall seconds accumulated by stage, cheap enough to be always on.

A :class:`StageClock` charges every interval of wall time between its first ``stage`` and the
last one's end to exactly one stage: the innermost open one (*self time*). A stage opened inside
another takes its time out of the outer one, so the stages of a frame add up to the frame's wall
time by construction (:meth:`StageClock.total`), and an outer stage such as ``solve`` is "the
rest" of its span once the stages inside it (``window_build``, ``linearisation``) have taken
theirs. A stage opened with ``absorb=True`` keeps everything inside it: the stages opened within
are not opened at all (``covariances`` keeps the linearisations that ``gtsam.Marginals`` runs).

The code being measured does not carry a clock around: it marks its stages with the module's
:func:`stage` (a context) or :func:`timed` (a decorator), which charge the clock made *active*
by :meth:`StageClock.activate` in this thread (a ``contextvars.ContextVar``), and do nothing
when no clock is active (a ``ContextVar.get`` and a call). :class:`gtvo.odometry.VisualOdometry`
activates its clock for each frame; the factors and the window only mark their stages.

The stages of a gtvo frame (:data:`FRAME_STAGES`; docs/evaluation.md, "Where a frame's time goes")::

    reading, tracking, point_selection, stereo_search, keyframe_setup, window_build,
    linearisation, solve, marginalisation, covariances, window_wait, outputs, other
"""

from __future__ import annotations

import contextvars
import functools
import time
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Mapping, Sequence, TypeVar

#: The stages of a gtvo run, in the order of a frame's work (what each covers: docs/evaluation.md).
FRAME_STAGES: tuple[str, ...] = ("reading", "tracking", "point_selection", "stereo_search", "keyframe_setup",
                                 "window_build", "linearisation", "solve", "marginalisation", "covariances",
                                 "window_wait", "outputs", "other")

_ACTIVE: contextvars.ContextVar[StageClock | None] = contextvars.ContextVar("gtvo_stage_clock", default=None)

F = TypeVar("F", bound=Callable[..., Any])


class StageClock:
    """Wall seconds by stage name, self time (module docstring).

    Args:
        stages: the stage names this clock accepts, in report order (default :data:`FRAME_STAGES`);
            a stage not among them raises ``ValueError`` (a misspelt hook fails loudly rather
            than hiding its time). ``None``: any name, added as first seen.
        timer: the clock read at every stage boundary, in seconds (default ``time.perf_counter``,
            wall time; ``time.process_time`` counts this process's CPU time, which other jobs on
            a shared machine disturb less, at about 1 us per read).

    Example::

        clock = StageClock()
        with clock.activate("other"):        # time outside any stage goes to "other"
            with stage("tracking"):
                ...
        clock.seconds["tracking"], clock.total()
    """

    def __init__(self, stages: Sequence[str] | None = FRAME_STAGES,
                 timer: Callable[[], float] = time.perf_counter) -> None:
        self.fixed = stages is not None
        self.timer = timer
        #: seconds charged to each stage (self time); every accepted stage is present, from 0.0
        self.seconds: dict[str, float] = {name: 0.0 for name in (stages or ())}
        #: how many times each stage was opened (not counted: inside an absorbing stage or inside itself)
        self.entries: dict[str, int] = {name: 0 for name in (stages or ())}
        self._stack: list[str] = []
        self._mark = 0.0  # start of the innermost open stage's running interval
        self._absorber = 0  # depth of the absorbing stage that is open (0: none)

    # --- the low-level pair (the decorator's path: no context object) ---------------------
    def enter(self, name: str, absorb: bool = False) -> bool:
        """Open stage ``name``; returns whether it was opened, which :meth:`leave` must be given: not
        inside an absorbing stage, nor when ``name`` is the innermost open stage already (its time
        goes there anyway; it is entered once)."""
        stack = self._stack
        if self._absorber or (stack and stack[-1] == name and not absorb):
            return False
        if name not in self.seconds:
            if self.fixed:
                raise ValueError(f"unknown stage {name!r}: this clock's stages are {', '.join(self.seconds)}")
            self.seconds[name] = 0.0
            self.entries[name] = 0
        now = self.timer()
        if stack:
            self.seconds[stack[-1]] += now - self._mark
        stack.append(name)
        self._mark = now
        self.entries[name] += 1
        if absorb:
            self._absorber = len(stack)
        return True

    def leave(self, opened: bool) -> None:
        """Close the innermost stage (``opened``: what its :meth:`enter` returned)."""
        if not opened:
            return
        now = self.timer()
        stack = self._stack
        self.seconds[stack[-1]] += now - self._mark
        if self._absorber == len(stack):
            self._absorber = 0
        stack.pop()
        self._mark = now

    @contextmanager
    def stage(self, name: str, absorb: bool = False) -> Iterator[None]:
        """A context: its time (less that of the stages opened inside, unless ``absorb``) goes to ``name``."""
        opened = self.enter(name, absorb)
        try:
            yield
        finally:
            self.leave(opened)

    @contextmanager
    def activate(self, root: str | None = None) -> Iterator[StageClock]:
        """Make this clock the one :func:`stage` and :func:`timed` charge in this thread (nests:
        the clock active before comes back at the end); with ``root``, that stage is open throughout
        and takes the time spent outside the others."""
        token = _ACTIVE.set(self)
        opened = self.enter(root) if root is not None else False
        try:
            yield self
        finally:
            self.leave(opened)
            _ACTIVE.reset(token)

    # --- reading -----------------------------------------------------------------------------
    def snapshot(self) -> dict[str, float]:
        """The seconds by stage now, the running interval of the open stage included."""
        out = dict(self.seconds)
        if self._stack:
            out[self._stack[-1]] += self.timer() - self._mark
        return out

    def total(self) -> float:
        """All seconds charged so far (every stage's, open ones included)."""
        return float(sum(self.snapshot().values()))

    def reset(self) -> None:
        """Forget all seconds and counts (only between stages: raises ``RuntimeError`` with one open)."""
        if self._stack:
            raise RuntimeError(f"cannot reset a StageClock with stages open: {self._stack}")
        for name in self.seconds:
            self.seconds[name] = 0.0
            self.entries[name] = 0


def active_clock() -> StageClock | None:
    """The clock activated in this thread (:meth:`StageClock.activate`), or None."""
    return _ACTIVE.get()


class _NoStage:
    """The context of :func:`stage` when no clock is active: does nothing."""

    __slots__ = ()

    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


_NO_STAGE = _NoStage()


def stage(name: str, absorb: bool = False) -> Any:
    """A context charging its time to stage ``name`` of the active clock (nothing without one)."""
    clock = _ACTIVE.get()
    if clock is None:
        return _NO_STAGE
    return clock.stage(name, absorb)


def timed(name: str, absorb: bool = False) -> Callable[[F], F]:
    """A decorator: every call of the function is stage ``name`` of the active clock (none: a plain call)."""

    def decorate(fn: F) -> F:
        @functools.wraps(fn)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            clock = _ACTIVE.get()
            if clock is None:
                return fn(*args, **kwargs)
            opened = clock.enter(name, absorb)
            try:
                return fn(*args, **kwargs)
            finally:
                clock.leave(opened)

        return wrapper  # type: ignore[return-value]

    return decorate


def per_frame_ms(seconds: Mapping[str, float], frames: int) -> dict[str, float]:
    """Seconds by stage -> mean milliseconds per frame (``frames`` > 0), same keys."""
    if frames <= 0:
        raise ValueError(f"per_frame_ms needs frames > 0, got {frames}")
    return {name: 1000.0 * s / frames for name, s in seconds.items()}
