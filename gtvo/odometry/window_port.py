"""The one port between the keyframer and the sliding window, and its in-process machine.

The keyframer drives the window through :class:`WindowPort` and nothing else, whichever machine
runs it (DSO hands a tracked frame to its mapper in one place, whatever the threading):

* :class:`LocalWindow`: the window (:class:`gtvo.odometry.window_link.WindowLink`) in this
  process; every optimisation's update is due at once (``window.parallel: false``, and ``auto``
  until the schedule decides).
* :class:`gtvo.odometry.window_worker.WindowWorker`: the same link in a worker process beside the
  front end; an update is due :data:`gtvo.odometry.window_worker.LAG` keyframes later
  (``window.parallel: true``, and ``auto`` once the schedule moves the window there:
  :meth:`WindowPort.on_second_core`; docs/window.md, "The window beside the tracker").

The port speaks plain data: a :class:`~gtvo.odometry.window_link.KeyframeForWindow` joins
(:meth:`WindowPort.join`), :class:`~gtvo.odometry.window_link.WindowUpdate` s come back when they
are due (:meth:`WindowPort.due`), and all at the run's end (:meth:`WindowPort.finish`). What the rest of the
run reads of the window (the rig offset, the wheel calibration, the keyframes' covariances, every
keyframe for the whole-log refinement, the marginal covariances for the report) is the port's
state, as of the updates handed out so far; what else the run asks of the window's state (the IMU's
figures at the end) is a function run on it where it is (:meth:`WindowPort.inspect`).
:func:`open_window` picks the machine from the settings.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Protocol, TypeVar, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from gtvo.config import OdometryConfig
from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.odometry.window_link import KeyframeForWindow, WindowLink, WindowUpdate
from gtvo.odometry.window_worker import WindowWorker, WorkerUsage
from gtvo.window import SlidingWindowOptimizer, WindowKeyframe, WindowSolverName
from gtvo.window.imu import ImuWindow
from gtvo.window.rig import RigOffset
from gtvo.window.wheel import WheelCalibration

FloatArray = NDArray[np.float64]
T = TypeVar("T")


@runtime_checkable
class WindowPort(Protocol):
    """The sliding window as the keyframer drives it and the run reads it (module docstring).

    Attributes:
        rig: the rig offset the window estimates, as of the last update handed out (None: not estimated).
        wheel: the wheel calibration the window estimates (the front end's object, its ``estimate``
            as of the last update handed out), None without wheel odometry in the window.
        covariances: frame index -> 6x6 pose covariance from the last update that included the keyframe.
        retain_keyframes: whether the window keeps every keyframe for the whole-log refinement
            (:meth:`every_keyframe`; ``refine.enabled``).
        backend_name: the window's back end, ``"lm"`` or ``"fixed_lag"``.
    """

    @property
    def rig(self) -> RigOffset | None: ...

    @property
    def wheel(self) -> WheelCalibration | None: ...

    @property
    def covariances(self) -> dict[int, FloatArray]: ...

    @property
    def retain_keyframes(self) -> bool: ...

    @property
    def backend_name(self) -> str: ...

    # -- driving the window --------------------------------------------------------------------
    def join(self, request: KeyframeForWindow, optimize: bool) -> None:
        """A new keyframe joins the window (the oldest leaves when it is full); ``optimize``: the
        window is optimised after it joins (its update comes from :meth:`due` or :meth:`finish`)."""

    def optimize(self) -> None:
        """Ask for an optimisation of the window as it is (its update comes with :meth:`finish`)."""

    def due(self, now: bool = False) -> list[WindowUpdate]:
        """The updates the front end applies now, oldest first (waits for them): those the
        machine's rule makes due, or with ``now`` every one (the newest keyframe waits for its own)."""

    def finish(self) -> list[WindowUpdate]:
        """The run's end: every update not handed out yet, oldest first (waits for all), and the
        state the run reads after it (:meth:`every_keyframe`) brought up to date."""

    def close(self) -> None:
        """Release the machine (idempotent); the state read so far stays readable."""

    # -- the window's state --------------------------------------------------------------------
    def keyframe_indices(self) -> list[int]:
        """The frame indices of the window's keyframes, oldest first."""

    def right_brightness(self) -> tuple[float, float] | None:
        """The right camera's brightness ``(a, b)`` relative to the left one from the newest window
        keyframe; None without one (or without a right image)."""

    def solver_name(self, requested: WindowSolverName) -> str:
        """The solver the window runs for ``requested`` (the fixed-lag back end: ``gtsam_isam2``)."""

    def rig_offset_covariance(self) -> FloatArray | None:
        """The rig offset's 2x2 marginal covariance at the window's state now (None: not estimated)."""

    def wheel_covariance(self) -> FloatArray | None:
        """The wheel calibration's marginal covariance at the window's state now, also kept in
        ``wheel.covariance``; None without wheel odometry or when indeterminate."""

    def every_keyframe(self) -> list[WindowKeyframe]:
        """Every keyframe the window has had (kept with :attr:`retain_keyframes`), oldest first, at
        their last optimised state: the whole-log refinement's input."""

    def worker_usage(self) -> WorkerUsage | None:
        """The worker process's own figures (CPU, memory, stages); None for a window in this process."""

    def inspect(self, probe: Callable[[SlidingWindowOptimizer], T]) -> T:
        """``probe`` run on the window's :class:`gtvo.window.SlidingWindowOptimizer` as it is now,
        where it is (a worker: ``probe`` is pickled, so a module-level function), and its value."""

    def on_second_core(self) -> WindowPort:
        """This window continued on the second core, in a worker process, from its state now (every
        update handed out; ``window.parallel: auto``); a worker's window is itself. The port to use
        from now on; this one is not used again."""


class LocalWindow:
    """The window in this process (a :class:`WindowPort`): each optimisation runs in :meth:`join`
    or :meth:`optimize` and its update is due at once.

    Args:
        camera: a :class:`StereoCamera` for stereo input, a :class:`PinholeCamera` for RGB-D.
        config: the run's settings.
        wheel: the wheel calibration the window estimates (LM back end), or None.
        imu: the IMU's owner in the window (:class:`gtvo.window.imu.ImuWindow`), or None.
    """

    def __init__(self, camera: StereoCamera | PinholeCamera, config: OdometryConfig,
                 wheel: WheelCalibration | None = None, imu: ImuWindow | None = None) -> None:
        self.link = WindowLink(camera, config, wheel=wheel, imu=imu)
        self._pending: list[WindowUpdate] = []

    @property
    def optimizer(self) -> SlidingWindowOptimizer:
        """The :class:`gtvo.window.SlidingWindowOptimizer` itself (in-process inspection)."""
        return self.link.window

    @property
    def rig(self) -> RigOffset | None:
        """The window's rig offset (its one owner), None when not estimated."""
        return self.link.window.rig

    @property
    def wheel(self) -> WheelCalibration | None:
        """The window's wheel calibration (the front end's object), None without wheels in the window."""
        return self.link.window.wheel

    @property
    def covariances(self) -> dict[int, FloatArray]:
        """Frame index -> 6x6 pose covariance from the last optimisation that included the keyframe."""
        return self.link.window.covariances

    @property
    def retain_keyframes(self) -> bool:
        """Whether the window keeps every keyframe for the whole-log refinement."""
        return self.link.window.retain_keyframes

    @property
    def backend_name(self) -> str:
        """The window's back end, ``"lm"`` or ``"fixed_lag"``."""
        return self.link.window.backend.name

    def join(self, request: KeyframeForWindow, optimize: bool) -> None:
        """:meth:`WindowPort.join`. In this process the front end's keyframes are the window's own
        (every update is applied at once): the keyframe is placed as given, its anchor unused."""
        self.link.join(dataclasses.replace(request, anchor=None))
        if optimize:
            self.optimize()

    def optimize(self) -> None:
        """:meth:`WindowPort.optimize`: runs now (nothing is due when the window had nothing to optimise)."""
        update = self.link.optimize()
        if update is not None:
            self._pending.append(update)

    def due(self, now: bool = False) -> list[WindowUpdate]:
        """:meth:`WindowPort.due`: every update (in this process none waits)."""
        out, self._pending = self._pending, []
        return out

    def finish(self) -> list[WindowUpdate]:
        """:meth:`WindowPort.finish`: every update (the state is the window's own)."""
        return self.due(now=True)

    def close(self) -> None:
        """Nothing to release."""

    def keyframe_indices(self) -> list[int]:
        """The frame indices of the window's keyframes now (those waiting for an optimisation included)."""
        return [w.index for w in self.link.window.keyframes]

    def right_brightness(self) -> tuple[float, float] | None:
        """:meth:`WindowPort.right_brightness` of the window now."""
        wk = self.link.window.keyframes
        if not wk or wk[-1].right is None:
            return None
        a, b = wk[-1].stereo_affine
        return float(a), float(b)

    def solver_name(self, requested: WindowSolverName) -> str:
        """:meth:`gtvo.window.SlidingWindowOptimizer.solver_name`."""
        return self.link.window.solver_name(requested)

    def rig_offset_covariance(self) -> FloatArray | None:
        """:meth:`gtvo.window.SlidingWindowOptimizer.rig_offset_covariance`."""
        return self.link.window.rig_offset_covariance()

    def wheel_covariance(self) -> FloatArray | None:
        """:meth:`gtvo.window.SlidingWindowOptimizer.wheel_covariance`."""
        return self.link.window.wheel_covariance()

    def every_keyframe(self) -> list[WindowKeyframe]:
        """:meth:`gtvo.window.SlidingWindowOptimizer.every_keyframe`."""
        return self.link.window.every_keyframe()

    def worker_usage(self) -> WorkerUsage | None:
        """None: no worker."""
        return None

    def inspect(self, probe: Callable[[SlidingWindowOptimizer], T]) -> T:
        """:meth:`WindowPort.inspect`: ``probe`` on the window in this process."""
        return probe(self.link.window)

    def on_second_core(self) -> WindowWorker:
        """:meth:`WindowPort.on_second_core`: a :class:`gtvo.odometry.window_worker.WindowWorker`
        that starts from this window's state (its link, pickled; the sensors stay the front end's)."""
        if self._pending:
            raise RuntimeError("the window moves to its worker only after its updates were handed out")
        if self.backend_name != "lm":
            raise RuntimeError("the fixed-lag back end's smoother cannot move to another process")
        return WindowWorker(self.link.camera, self.link.config, link=self.link)


def open_window(camera: StereoCamera | PinholeCamera, config: OdometryConfig,
                wheel: WheelCalibration | None = None, imu: ImuWindow | None = None) -> WindowPort:
    """The window's machine for ``config``: a :class:`gtvo.odometry.window_worker.WindowWorker`
    with ``window.parallel: true``, else a :class:`LocalWindow` (with ``auto`` the schedule may move
    it to a worker later: :meth:`WindowPort.on_second_core`). ``wheel``: the wheel calibration the
    window estimates (the LM back end's; the fixed-lag back end leaves it at its prior); ``imu``:
    the IMU's owner in the window (:class:`gtvo.window.imu.ImuWindow`), or None.

    Raises:
        InputError: the IMU with the fixed-lag back end (:meth:`gtvo.window.SlidingWindowOptimizer.use_imu`).
    """
    wheel = wheel if config.window.backend == "lm" else None
    if config.window.parallel is True:
        return WindowWorker(camera, config, wheel, imu)
    return LocalWindow(camera, config, wheel, imu)
