"""The sliding window: :class:`SlidingWindowOptimizer` with its two back ends.

* :class:`LMBackend` (``backend="lm"``): each window re-solved by LM (GTSAM or hand-rolled), the
  keyframes that leave marginalised by :func:`gtvo.window.marginal.marginalize`.
* :class:`gtvo.window.fixed_lag.FixedLagBackend` (``backend="fixed_lag"``): the window kept in
  ``gtsam.IncrementalFixedLagSmoother`` (iSAM2).
"""

from __future__ import annotations


import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera
from gtvo.core.keys import rig_offset_key
from gtvo.core.timing import stage
from gtvo.errors import InputError
from gtvo.window.config import MarginalPrior, WindowConfig, WindowKeyframe, WindowResult, WindowSolverName, WindowState
from gtvo.window.gtsam_solver import solve_gtsam
from gtvo.window.handrolled import solve_handrolled, window_cost
from gtvo.window.marginal import marginalize
from gtvo.window.fixed_lag import FixedLagBackend
from gtvo.window.problem import (RIG_SIGNIFICANCE, build_graph, observation_counts, rig_honest_sigma,
                                 rig_offset_significant, visible_targets)

FloatArray = NDArray[np.float64]


class SlidingWindowOptimizer:
    """A window of keyframes optimised jointly, with marginalisation of the keyframes that leave.

    Args:
        camera: left-camera intrinsics (all keyframes share them).
        baseline: stereo baseline (m), or None for RGB-D input.
        config: window settings.

    Example::

        window = SlidingWindowOptimizer(camera, baseline)
        window.add_keyframe(WindowKeyframe(...))   # marginalises the oldest when full
        result = window.optimize("gtsam")          # keyframes updated in place
    """

    def __init__(self, camera: PinholeCamera, baseline: float | None, config: WindowConfig | None = None,
                 rig_offset: FloatArray | None = None) -> None:
        self.camera = camera
        self.baseline = baseline
        self.config = config or WindowConfig()
        #: the stereo rig's offset (delta_x, delta_y) (px), estimated by every optimisation when
        #: given (its starting value; docs/window.md, "Rig calibration"), else None (rectified model)
        self.rig_offset: FloatArray | None = None
        if rig_offset is not None:
            if baseline is None:
                raise InputError("a rig offset needs a stereo window (a baseline)")
            if self.config.backend != "lm":
                raise InputError("the rig offset is estimated by the 'lm' window backend only")
            self.rig_offset = np.asarray(rig_offset, dtype=float).reshape(2).copy()
        #: whether ``delta_x`` is estimated: it is held at its start value (:attr:`rig_x_start`)
        #: until a full window's data put it significantly away from it (:meth:`LMBackend.optimize`)
        self.rig_x_estimated = False
        self.rig_x_start = 0.0 if self.rig_offset is None else float(self.rig_offset[0])
        #: the last test of ``delta_x`` while held: ``(free estimate, its marginal sigma)`` px, None
        #: before the window is first full; and the number of full windows solved with it held
        self.rig_x_test: tuple[float, float] | None = None
        self.rig_x_held_windows = 0
        #: both offsets held at 0: the window solves the rectified model (no rig variable) and tests
        #: the offset as a whole, releasing both axes when either is significant (set by the
        #: odometry when the first pair's vertical offset is not; docs/window.md, "Rig calibration")
        self.rig_rectified = False
        #: ``delta_y`` was known (significant) from the first stereo pair and is corrected: ``delta_x``
        #: is then released at the first full window whatever its test says (set by the odometry)
        self.rig_y_known = False
        #: the last test of the offset as a whole while rectified: ``(free estimate, marginal sigmas)``
        self.rig_test: tuple[FloatArray, FloatArray] | None = None
        self.keyframes: list[WindowKeyframe] = []
        self.n_removed = 0  # keyframes that left the window (not kept: they hold images)
        self.results: list[WindowResult] = []
        #: frame index -> 6x6 pose covariance from the last optimisation the keyframe was part of
        #: (``config.covariances``; docs/window.md, "Pose covariances")
        self.covariances: dict[int, FloatArray] = {}
        #: per keyframe of the last optimised window, the positions of its targets (:func:`visible_targets`)
        self.last_targets: list[list[int]] = []
        self.backend: LMBackend | FixedLagBackend = FixedLagBackend() if self.config.backend == "fixed_lag" else LMBackend()

    def add_keyframe(self, keyframe: WindowKeyframe) -> None:
        """Append a keyframe; when the window is full, the oldest leaves first (marginalised)."""
        if any(k.index == keyframe.index for k in self.keyframes):
            raise InputError(f"keyframe {keyframe.index} is already in the window")
        while len(self.keyframes) >= self.config.size:
            self.remove_oldest()
        self.keyframes.append(keyframe)

    def remove_oldest(self) -> WindowKeyframe:
        """Remove the oldest keyframe: marginalised into the prior (or dropped, per the config).

        With the fixed-lag backend the smoother marginalises it at the next :meth:`optimize`.
        """
        with stage("marginalisation", absorb=True):
            kf = self.backend.remove_oldest(self)
        self.n_removed += 1
        return kf

    @property
    def marginal(self) -> MarginalPrior | None:
        """The prior left by the keyframes that were marginalised (LM back end; None before, and for fixed-lag)."""
        return getattr(self.backend, "marginal", None)

    def cost(self) -> float:
        """The window cost at the current state (W evaluated at this state)."""
        return window_cost(self.camera, self.baseline, self.keyframes, self.config, self.marginal,
                           rig_offset=_solved_rig_offset(self))

    def rig_offset_covariance(self) -> FloatArray | None:
        """The 2x2 marginal covariance (px^2) of the rig offset at the current state: the window's
        graph (host factors, priors, marginal prior) linearised once, ``gtsam.Marginals``.
        None when the rig offset is not estimated or the window has no host factor yet."""
        built = self._rig_graph()
        if built is None:
            return None
        graph, values = built
        return np.asarray(gtsam.Marginals(graph, values).marginalCovariance(rig_offset_key()), dtype=float)

    def _rig_graph(self) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values] | None:
        """The window's graph and values at the current state with the rig offset a free variable,
        or None when it is not estimated (or no host factor exists yet)."""
        if self.rig_offset is None or len(self.keyframes) < 2 or self.config.backend != "lm":
            return None
        targets = visible_targets(self.camera, self.keyframes, self.config)
        if not any(targets):
            return None
        graph, values, _ = build_graph(self.camera, self.baseline, self.keyframes, self.config, self.marginal, targets,
                                       self.rig_offset)
        return graph, values

    def rig_free_estimate(self) -> tuple[FloatArray, FloatArray] | None:
        """What the window's data say about the rig offset while it is held: one Gauss-Newton step
        from the current state on the window's graph without the hold (the estimate ``(delta_x,
        delta_y)``), and the marginal sigmas there (px). None when the rig offset is not estimated or
        there is no host factor."""
        built = self._rig_graph()
        if built is None:
            return None
        graph, values = built
        linear = graph.linearize(values)
        step = np.asarray(linear.optimize().at(rig_offset_key()), dtype=float).reshape(2)
        cov = gtsam.Marginals(linear, values).marginalCovariance(rig_offset_key())
        assert self.rig_offset is not None
        return self.rig_offset + step, np.sqrt(np.maximum(np.diag(cov), 0.0))

    def rig_x_free_estimate(self) -> tuple[float, float] | None:
        """:meth:`rig_free_estimate` for ``delta_x`` alone: ``(estimate, marginal sigma)`` px."""
        test = self.rig_free_estimate()
        return None if test is None else (float(test[0][0]), float(test[1][0]))

    def optimize(self, solver: WindowSolverName = "gtsam") -> WindowResult | None:
        """Optimise the window (None when fewer than two keyframes); keyframes are updated in place.

        ``solver`` chooses the LM path's solver; the fixed-lag backend ignores it (GTSAM's smoother).
        """
        self.last_targets = []
        if len(self.keyframes) < 2:
            return None
        targets = visible_targets(self.camera, self.keyframes, self.config)
        if not any(targets):
            return None
        with stage("solve"):  # less the stages inside: build, linearisation, covariances
            res = self.backend.optimize(self, targets, solver)
        if res.covariances is not None:
            self.covariances.update(res.covariances)
        self.results.append(res)
        self.last_targets = targets
        return res

    def solver_name(self, requested: WindowSolverName) -> str:
        """The solver that :meth:`optimize` with ``solver=requested`` runs (the fixed-lag back end
        ignores the request: gtsam's iSAM2)."""
        return self.backend.solver_name(requested)

    def observation_counts(self) -> dict[int, NDArray[np.int64]]:
        """Per keyframe index of the last optimised window, per hosted point: the number of other
        keyframes the optimisation compared it with and in which it is seen (the host not counted;
        all zeros before the first optimisation)."""
        if len(self.last_targets) != len(self.keyframes):
            return {k.index: np.zeros(len(k), dtype=np.int64) for k in self.keyframes}
        counts = observation_counts(self.camera, self.keyframes, self.last_targets)
        return {k.index: c for k, c in zip(self.keyframes, counts)}



class LMBackend:
    """Each window re-solved by Levenberg-Marquardt; keyframes that leave are marginalised into a prior."""

    name = "lm"

    def __init__(self) -> None:
        self.marginal: MarginalPrior | None = None

    def solver_name(self, requested: WindowSolverName) -> str:
        """The LM back end runs the requested solver."""
        return str(requested)

    def remove_oldest(self, window: WindowState) -> WindowKeyframe:
        """Marginalise the oldest keyframe into :attr:`marginal` (or drop it, ``marginalize=False``)."""
        if window.config.marginalize:
            self.marginal = marginalize(window.camera, window.baseline, window.keyframes, window.config,
                                        self.marginal, 0, _solved_rig_offset(window))
        return window.keyframes.pop(0)

    def optimize(self, window: WindowState, targets: list[list[int]],
                 solver: WindowSolverName) -> WindowResult:
        """Solve the window with ``solver`` ("gtsam" or "handrolled"); keyframes updated in place."""
        solve = {"gtsam": solve_gtsam, "handrolled": solve_handrolled}.get(solver)
        if solve is None:
            raise InputError(f"unknown window solver {solver!r}: use 'gtsam' or 'handrolled'")
        rig = _solved_rig_offset(window)
        # delta_x trades against the scale: it is held at its start value until a full window's data
        # put it clearly away from it (docs/window.md, "Rig calibration": on a rectified rig,
        # estimating it adds scale error; the marginalisation prior never holds the hold); with
        # ``rig_rectified`` both offsets are held at 0: no rig variable, the rectified model
        hold = None if rig is None or window.rig_x_estimated else window.rig_x_start  # type: ignore[attr-defined]
        res = solve(window.camera, window.baseline, window.keyframes, window.config, self.marginal, targets,
                    rig_offset=rig, rig_hold_x=hold)
        full = self.marginal is not None or len(window.keyframes) >= window.config.size
        if getattr(window, "rig_offset", None) is not None and rig is None:  # rectified: test both axes
            if full and self._rig_significant(window):
                window.rig_rectified = False  # type: ignore[attr-defined]
                window.rig_x_estimated = True  # type: ignore[attr-defined]
                res = solve(window.camera, window.baseline, window.keyframes, window.config, self.marginal,
                            targets, rig_offset=window.rig_offset, rig_hold_x=None)  # type: ignore[attr-defined]
                window.rig_offset = res.rig_offset.copy()  # type: ignore[attr-defined, union-attr]
            return res
        if rig is None or res.rig_offset is None:
            return res
        window.rig_offset = res.rig_offset.copy()  # type: ignore[attr-defined]
        # a delta_y known and corrected from the first pair leaves delta_x held no longer than the
        # first full window: held at 0 it would bias the scale the corrected delta_y moved
        if hold is not None and full and (window.rig_y_known or self._rig_x_significant(window)):  # type: ignore[attr-defined]
            window.rig_x_estimated = True  # type: ignore[attr-defined]
            # solved again with delta_x free, from the held state (LM's damping, not the test's
            # linear step, decides how far it goes along the flat scale direction)
            res = solve(window.camera, window.baseline, window.keyframes, window.config, self.marginal, targets,
                        rig_offset=window.rig_offset, rig_hold_x=None)  # type: ignore[attr-defined]
            window.rig_offset = res.rig_offset.copy()  # type: ignore[attr-defined, union-attr]
        return res

    @staticmethod
    def _rig_significant(window: WindowState) -> bool:
        """Every ``config.size``-th full window solved with the rig held at the rectified model (from
        the first), test the offset as a whole: is either axis of the data's estimate
        (:meth:`SlidingWindowOptimizer.rig_free_estimate`; ``delta_x``'s kept in ``window.rig_x_test``)
        more than :data:`RIG_SIGNIFICANCE` error bars (:func:`rig_honest_sigma`) from 0?"""
        n = window.rig_x_held_windows  # type: ignore[attr-defined]
        window.rig_x_held_windows = n + 1  # type: ignore[attr-defined]
        if n % window.config.size:
            return False
        test = window.rig_free_estimate()  # type: ignore[attr-defined]
        if test is None:
            return False
        estimate, sigma = test
        window.rig_x_test = (float(estimate[0]), float(sigma[0]))  # type: ignore[attr-defined]
        window.rig_test = (estimate, sigma)  # type: ignore[attr-defined]
        return any(rig_offset_significant(float(estimate[axis]), float(sigma[axis]), axis) for axis in (0, 1))

    @staticmethod
    def _rig_x_significant(window: WindowState) -> bool:
        """Every ``config.size``-th full window solved with ``delta_x`` held (from the first), test it:
        is the data's estimate (:meth:`SlidingWindowOptimizer.rig_x_free_estimate`, kept in
        ``window.rig_x_test``) more than :data:`RIG_SIGNIFICANCE` error bars (:func:`rig_honest_sigma`)
        from the start value?"""
        n = window.rig_x_held_windows  # type: ignore[attr-defined]
        window.rig_x_held_windows = n + 1  # type: ignore[attr-defined]
        if n % window.config.size:
            return False
        test = window.rig_x_free_estimate()  # type: ignore[attr-defined]
        if test is None:
            return False
        window.rig_x_test = test  # type: ignore[attr-defined]
        estimate, sigma = test
        return abs(estimate - window.rig_x_start) > RIG_SIGNIFICANCE * rig_honest_sigma(sigma, 0)  # type: ignore[attr-defined]


def _solved_rig_offset(window: WindowState) -> FloatArray | None:
    """The rig offset the window's graph carries as a variable: None without rig calibration and
    while both offsets are held at the rectified model (``rig_rectified``)."""
    rig = getattr(window, "rig_offset", None)
    return None if rig is None or getattr(window, "rig_rectified", False) else rig
