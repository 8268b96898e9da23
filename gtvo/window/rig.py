"""The stereo rig's offset: one home for its estimate, its hold, its significance test and its error bar.

The window estimates the right image's offset ``(delta_x, delta_y)`` (px) against its rectification
(docs/window.md, "Rig calibration"). :class:`RigOffset` is that estimate's only owner: the window
(:class:`gtvo.window.SlidingWindowOptimizer`, attribute ``rig``) updates it after every
optimisation, the keyframes' stereo search and the report read it. Nobody keeps a copy (but a parallel
window's front end, which reads the worker's as of its last applied update: docs/window.md).

* The first stereo pair's 2-D search gives ``delta_y`` (:meth:`RigOffset.start_from`). When it is
  not significant (:func:`offset_significant`), the window solves the rectified model (no rig
  variable: :attr:`RigOffset.rectified`, :attr:`RigOffset.solved_offset` None) and every ``size``
  full windows tests the offset as a whole (:meth:`RigOffset.test_release_both`): once either axis
  is significant, both are released for the rest of the run. A rig that stays rectified runs bit
  for bit as without calibration.
* When the front end finds that the first pair's images cannot carry the offset (too dark or too
  flat: :func:`gtvo.frontend.rig_offset.stereo_contrast`), the window solves the rectified model for
  the whole run and never tests the offset (:attr:`RigOffset.withheld` says why; the report and
  :func:`rig_warning` say it too).
* When it is significant, ``delta_y`` is corrected and a free variable of every window, and
  ``delta_x`` (which trades against the scale) is held at its start value
  (:attr:`RigOffset.hold_x`) until the first full window (:meth:`RigOffset.test_release`): held at
  0 it would bias the scale the corrected ``delta_y`` moved.
* The error bar (:func:`rig_honest_sigma`) is the window's marginal sigma and the method's measured
  error :data:`RIG_METHOD_SIGMA` in quadrature; :meth:`RigOffset.report` gives the figures
  ``report.json`` holds and :func:`rig_warning` the one line a run prints for a clearly large offset.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: The rig offset estimate's own error (px; delta_x, delta_y): what the marginal covariance does not
#: see (it assumes independent residuals and an exact model). Measured on logs of known rig
#: (docs/window.md, "Rig calibration", "Uncertainty"): the first full window's delta_x is off by
#: -0.10 to +0.14 px (RMS about 0.09) on synthetic logs of exact rig and by +0.06 to +0.10 px on
#: shifted KITTI_sequence_1, where its marginal sigma says 0.01-0.04 px; delta_y within 0.011 px on
#: the synthetic logs and 0.04 px of an independent estimate on KITTI.
RIG_METHOD_SIGMA = (0.10, 0.05)
#: delta_x is released when it is this many honest sigmas (:func:`rig_honest_sigma`) from its start value.
RIG_SIGNIFICANCE = 3.0
#: An offset above this (px) is reported as a rig problem. Half a pixel is about the disparity
#: error that makes a 1 % scale error at 50 px of disparity (a point ~10 m away on KITTI).
WARN_OFFSET_PX = 0.5
#: ... when it is also this many standard deviations from zero.
WARN_SIGMAS = 3.0


def rig_honest_sigma(marginal_sigma: float, axis: int) -> float:
    """The rig offset's error bar on ``axis`` (0: x, 1: y): the marginal sigma and
    :data:`RIG_METHOD_SIGMA` in quadrature."""
    return float(np.hypot(marginal_sigma, RIG_METHOD_SIGMA[axis]))


def offset_significant(value: float, marginal_sigma: float, axis: int, start: float = 0.0) -> bool:
    """Whether an offset ``value`` (px) on ``axis`` (0: x, 1: y) is more than
    :data:`RIG_SIGNIFICANCE` error bars (:func:`rig_honest_sigma` of ``marginal_sigma``) from ``start``."""
    return abs(float(value) - float(start)) > RIG_SIGNIFICANCE * rig_honest_sigma(marginal_sigma, axis)


class RigOffset:
    """The estimate of the right image's offset ``(delta_x, delta_y)`` (px) and its state.

    Args:
        start: the starting value (usually zero; :meth:`start_from` sets ``delta_y`` from the
            first stereo pair).

    Attributes:
        offset: the current estimate ``[delta_x, delta_y]`` (px), updated by the window.
        rectified: both offsets held at 0: the window solves the rectified model, no rig variable.
        y_known: ``delta_y`` was significant in the first pair and is corrected: ``delta_x`` is
            released at the first full window.
        x_estimated: whether ``delta_x`` has been released (it is held at :attr:`x_start` until then).
        x_start: the value ``delta_x`` is held at.
        x_test: the last test of ``delta_x`` while held, ``(free estimate, marginal sigma)`` px;
            None before the window is first full.
        test: the last test of the offset as a whole while rectified, ``(free estimate, marginal
            sigmas)`` (2,) each, px.
        x_held_windows: full windows solved with ``delta_x`` held.
        initial: the first stereo pair's vertical-offset search
            (:class:`gtvo.frontend.rig_offset.VerticalOffset`), None before it ran.
        withheld: why the images cannot carry the offset (the rectified model is kept for the
            run, never tested), None when they can.
    """

    def __init__(self, start: ArrayLike = (0.0, 0.0)) -> None:
        self.offset: FloatArray = np.asarray(start, dtype=float).reshape(2).copy()
        self.rectified = False
        self.y_known = False
        self.x_estimated = False
        self.x_start = float(self.offset[0])
        self.x_test: tuple[float, float] | None = None
        self.test: tuple[FloatArray, FloatArray] | None = None
        self.x_held_windows = 0
        self.initial: Any = None
        self.withheld: str | None = None

    @property
    def solved_offset(self) -> FloatArray | None:
        """The offset the window's graph carries as a variable; None while :attr:`rectified`."""
        return None if self.rectified else self.offset

    @property
    def hold_x(self) -> float | None:
        """The value ``delta_x`` is held at in the next optimisation, None once it is released (and
        while :attr:`rectified`: there is no variable to hold)."""
        return None if self.x_estimated or self.rectified else self.x_start

    def start_from(self, initial: Any, withheld: str | None = None) -> None:
        """Start from the first stereo pair's vertical-offset search ``initial`` (``delta_y`` and its
        standard error ``sigma``): a significant ``delta_y`` is corrected (:attr:`y_known`),
        otherwise the window starts rectified (:attr:`rectified`); ``delta_x`` from 0. With
        ``withheld`` (why the images cannot carry the offset) the window stays rectified for the
        whole run, whatever ``initial`` says."""
        self.initial = initial
        self.withheld = withheld
        if withheld is None and offset_significant(initial.delta_y, initial.sigma, 1):
            self.offset = np.array([0.0, float(initial.delta_y)])
            self.y_known = True
        else:
            self.offset = np.zeros(2)
            self.rectified = True

    def _due(self, window_size: int) -> bool:
        """Count a full window solved while held; True at every ``window_size``-th (from the first)."""
        n = self.x_held_windows
        self.x_held_windows = n + 1
        return n % window_size == 0

    def test_release_both(self, window_size: int,
                          free_estimate: Callable[[], tuple[FloatArray, FloatArray] | None]) -> bool:
        """While :attr:`rectified`: count a full window; every ``window_size``-th one (from the
        first), test the offset as a whole (``free_estimate()``: ``(estimate, marginal sigmas)``,
        kept in :attr:`test`, ``delta_x``'s in :attr:`x_test`): is either axis more than
        :data:`RIG_SIGNIFICANCE` error bars from 0? Then both are released and True returned.
        Never while :attr:`withheld`."""
        if self.withheld is not None or not self._due(window_size):
            return False
        test = free_estimate()
        if test is None:
            return False
        estimate, sigma = test
        self.test = (estimate, sigma)
        self.x_test = (float(estimate[0]), float(sigma[0]))
        if not any(offset_significant(float(estimate[axis]), float(sigma[axis]), axis) for axis in (0, 1)):
            return False
        self.rectified = False
        self.x_estimated = True
        return True

    def test_release(self, window_size: int, free_estimate: Callable[[], tuple[float, float] | None]) -> bool:
        """With ``delta_x`` held at a full window: released at once when :attr:`y_known`; else every
        ``window_size``-th such window (from the first), test it: is the data's estimate
        (``free_estimate()``: ``(estimate, marginal sigma)``, kept in :attr:`x_test`) more than
        :data:`RIG_SIGNIFICANCE` error bars from :attr:`x_start`? Then ``delta_x`` is released
        (:attr:`x_estimated`) and True returned."""
        if self.y_known:
            self.x_estimated = True
            return True
        if not self._due(window_size):
            return False
        test = free_estimate()
        if test is None:
            return False
        self.x_test = test
        estimate, sigma = test
        if offset_significant(estimate, sigma, 0, self.x_start):
            self.x_estimated = True
        return self.x_estimated

    def report(self, covariance: FloatArray | None) -> dict[str, Any]:
        """The figures ``report.json`` holds (docs/evaluation.md): ``rig_calibration`` (True),
        ``rig_offset_px`` ``[delta_x, delta_y]``, ``rig_offset_marginal_sigma_px`` (from
        ``covariance``, the final window's 2x2 marginal, None if it has none; for ``delta_x``
        while it is held, its last test's, None if never tested), ``rig_offset_sigma_px`` (the
        error bar: :func:`rig_honest_sigma`; None where the marginal one is),
        ``rig_offset_x_estimated``, ``rig_offset_x_tested_px`` (the last test's estimate while
        held, None if never tested), ``rig_initial_delta_y_px`` (the first pair's 2-D search; None
        when it found none) and ``rig_offset_withheld`` (why the images cannot carry the offset,
        None when they can)."""
        out: dict[str, Any] = {"rig_calibration": True, "rig_offset_px": [float(x) for x in self.offset]}
        sigma = None if covariance is None else [float(np.sqrt(max(covariance[i, i], 0.0))) for i in range(2)]
        test = self.x_test
        if sigma is not None and not self.x_estimated:
            # held: the final window's marginal says nothing about delta_x; its last test does
            sigma[0] = None if test is None else test[1]
        out["rig_offset_marginal_sigma_px"] = sigma
        out["rig_offset_sigma_px"] = None if sigma is None else [
            None if s is None else rig_honest_sigma(s, axis) for axis, s in enumerate(sigma)]
        out["rig_offset_x_estimated"] = bool(self.x_estimated)
        out["rig_offset_x_tested_px"] = None if test is None or self.x_estimated else test[0]
        initial = None if self.initial is None else float(self.initial.delta_y)
        out["rig_initial_delta_y_px"] = initial if initial is not None and np.isfinite(initial) else None
        out["rig_offset_withheld"] = self.withheld
        return out


def rig_warning(report: dict[str, Any]) -> str | None:
    """The warning line for a rig offset estimated large and clearly, or for one the images could
    not carry (None: nothing to say), from the figures of :meth:`RigOffset.report`."""
    withheld = report.get("rig_offset_withheld")
    if withheld:
        return f"{withheld}: the rig offset is not estimated, the rectified model is kept"
    offset = report.get("rig_offset_px")
    if not offset:
        return None
    sigma = report.get("rig_offset_sigma_px") or [0.0, 0.0]
    parts = []
    for value, s, axis in zip(offset, sigma, ("horizontally", "vertically")):
        if s is not None and abs(value) > WARN_OFFSET_PX and abs(value) > WARN_SIGMAS * s:
            parts.append(f"{value:+.1f} px {axis}")
    if not parts:
        return None
    return f"the right camera is offset by {' and '.join(parts)} from its calibration: check the rig"
