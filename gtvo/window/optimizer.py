"""The sliding window: :class:`SlidingWindowOptimizer` with its two back ends.

* :class:`LMBackend` (``backend="lm"``): each window re-solved by LM (GTSAM or hand-rolled), the
  keyframes that leave marginalised by :func:`gtvo.window.marginal.marginalize`.
* :class:`gtvo.window.fixed_lag.FixedLagBackend` (``backend="fixed_lag"``): the window kept in
  ``gtsam.IncrementalFixedLagSmoother`` (iSAM2).
"""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera
from gtvo.core.keys import calibration_key, rig_offset_key
from gtvo.core.timing import stage
from gtvo.errors import InputError
from factors.compact_image import compact_image
from factors.params import PhotometricConfig
from gtvo.window.config import MarginalPrior, WindowConfig, WindowKeyframe, WindowResult, WindowSolverName
from gtvo.window.gtsam_solver import solve_gtsam
from gtvo.window.handrolled import solve_handrolled, window_cost
from gtvo.window import residual_memo
from gtvo.window.marginal import marginalize
from gtvo.window.fixed_lag import FixedLagBackend
from gtvo.window.problem import (RigVariable, SolvableWindow, WindowMembers, WindowProblem, WindowSettings,
                                 build_graph, observation_counts, visible_targets)
from gtvo.window.rig import RigOffset
from gtvo.window.imu import ImuWindow
from gtvo.window.wheel import WheelCalibration

FloatArray = NDArray[np.float64]


class SlidingWindowOptimizer:
    """A window of keyframes optimised jointly, with marginalisation of the keyframes that leave.

    Args:
        camera: left-camera intrinsics (all keyframes share them).
        baseline: stereo baseline (m), or None for RGB-D input.
        settings: the window's settings (:class:`gtvo.window.config.WindowConfig`) or, with the
            photometric model of its residuals (noise, Huber threshold, pattern; a VO run's
            ``OdometryConfig.photometric``), a :class:`gtvo.window.problem.WindowSettings`; default
            :class:`WindowConfig`'s and :class:`factors.params.PhotometricConfig`'s.
        rig_offset: the rig offset's starting value when it is estimated (docs/window.md, "Rig calibration").
        wheel: the wheel odometry and its calibration (:class:`gtvo.window.wheel.WheelCalibration`;
            LM backend only): wheel factors between consecutive keyframes, the calibration a
            variable of every window (docs/window.md, "Wheel odometry"); None: no wheels.

    Example::

        window = SlidingWindowOptimizer(camera, baseline)
        window.add_keyframe(WindowKeyframe(...))   # marginalises the oldest when full
        result = window.optimize("gtsam")          # keyframes updated in place
    """

    def __init__(self, camera: PinholeCamera, baseline: float | None,
                 settings: WindowSettings | WindowConfig | None = None, rig_offset: FloatArray | None = None,
                 wheel: WheelCalibration | None = None) -> None:
        self.camera = camera
        self.baseline = baseline
        settings = WindowSettings(settings) if isinstance(settings, WindowConfig) else settings or WindowSettings()
        self.config: WindowConfig = settings.config
        self.photometric: PhotometricConfig = settings.photometric
        #: the stereo rig's offset and its state (:class:`gtvo.window.rig.RigOffset`), estimated by
        #: every optimisation when a ``rig_offset`` start is given (docs/window.md, "Rig
        #: calibration"), else None (rectified model)
        self.rig: RigOffset | None = None
        if rig_offset is not None:
            if baseline is None:
                raise InputError("a rig offset needs a stereo window (a baseline)")
            if self.config.backend != "lm":
                raise InputError("the rig offset is estimated by the 'lm' window backend only")
            self.rig = RigOffset(rig_offset)
        if wheel is not None and self.config.backend != "lm":
            raise InputError("wheel odometry is used by the 'lm' window backend only")
        #: the wheel calibration's one owner, updated by every optimisation (None: no wheel odometry)
        self.wheel: WheelCalibration | None = wheel
        #: the IMU's one owner: gravity, the keyframes' velocities and biases (None: no IMU; :meth:`use_imu`)
        self.imu: ImuWindow | None = None
        self.keyframes: list[WindowKeyframe] = []
        self.n_removed = 0  # keyframes that left the window (not kept unless retain_keyframes: they hold images)
        #: keep the keyframes that leave in :attr:`retired` (the whole-log refinement's input,
        #: :meth:`every_keyframe`); False (the default) drops them with their images
        self.retain_keyframes = False
        #: the keyframes that left the window, oldest first, as they left (with ``retain_keyframes``),
        #: their images as :class:`factors.compact_image.CompactGradientImage` (the grey levels only;
        #: the sampler's records are packed again when the refinement samples them)
        self.retired: list[WindowKeyframe] = []
        self.results: list[WindowResult] = []
        #: frame index -> 6x6 pose covariance from the last optimisation the keyframe was part of
        #: (``config.covariances``; docs/window.md, "Pose covariances")
        self.covariances: dict[int, FloatArray] = {}
        #: per keyframe of the last optimised window, the positions of its targets (:func:`visible_targets`)
        self.last_targets: list[list[int]] = []
        self.backend: LMBackend | FixedLagBackend = FixedLagBackend() if self.config.backend == "fixed_lag" else LMBackend()

    @property
    def sensors(self) -> tuple[WheelCalibration | ImuWindow, ...]:
        """The window's sensors beyond the cameras, those it has (the wheel calibration, the IMU):
        what a window continued in another process carries with it."""
        return tuple(s for s in (self.wheel, self.imu) if s is not None)

    def use_imu(self, imu: ImuWindow) -> None:
        """Estimate with the IMU (:class:`gtvo.window.imu.ImuWindow`, a sensor of every problem; docs/imu.md),
        before the first keyframe joins."""
        if self.config.backend != "lm":
            raise InputError("the IMU is used by the 'lm' window backend only: drop --window-backend fixed-lag or "
                             "add --no-imu")
        if self.keyframes:
            raise InputError("the IMU joins the window before its first keyframe")
        self.imu = imu

    def add_keyframe(self, keyframe: WindowKeyframe) -> None:
        """Append a keyframe; when the window is full, the oldest leaves first (marginalised)."""
        if any(k.index == keyframe.index for k in self.keyframes):
            raise InputError(f"keyframe {keyframe.index} is already in the window")
        while len(self.keyframes) >= self.config.size:
            self.remove_oldest()
        self.keyframes.append(keyframe)
        if self.imu is not None:
            self.imu.keyframe_added(self.keyframes)

    def remove_oldest(self) -> WindowKeyframe:
        """Remove the oldest keyframe: marginalised into the prior (or dropped, per the config).

        With the fixed-lag backend the smoother marginalises it at the next :meth:`optimize`.
        """
        with stage("marginalisation", absorb=True):
            kf = self.backend.remove_oldest(self)
        self.n_removed += 1
        if self.retain_keyframes:  # its images compact: grey levels only (factors.compact_image)
            self.retired.append(dataclasses.replace(kf, image=compact_image(kf.image), right=compact_image(kf.right)))
        return kf

    def every_keyframe(self) -> list[WindowKeyframe]:
        """The keyframes that left the window (kept with ``retain_keyframes``) and those in it, oldest first."""
        return self.retired + self.keyframes

    @property
    def marginal(self) -> MarginalPrior | None:
        """The prior left by the keyframes that were marginalised (LM back end; None before, and for fixed-lag)."""
        return getattr(self.backend, "marginal", None)

    def solved_rig(self) -> RigVariable | None:
        """The rig offset as a variable of the window's problem, not held: None while it is not
        estimated or rectified."""
        offset = None if self.rig is None else self.rig.solved_offset
        return None if offset is None else RigVariable(offset)

    def problem(self, targets: list[list[int]] | None = None, rig: RigVariable | None = None) -> WindowProblem:
        """The window's problem at its current state (:class:`gtvo.window.problem.WindowProblem`):
        its keyframes (``targets``: theirs, None: chosen at the first use), its marginalisation
        prior, its sensors (the wheel calibration, the IMU) and ``rig`` (None: no rig variable;
        :meth:`solved_rig`: the window's)."""
        settings = WindowSettings(self.config, self.photometric, keep_residuals=True)  # gtvo.window.residual_memo
        return WindowProblem.build(WindowMembers(self.camera, self.baseline, self.keyframes, targets),
                                   settings, self.marginal, rig,
                                   (self.wheel, self.imu))  # the IMU: gtvo.window.imu

    def cost(self) -> float:
        """The window cost at the current state (W evaluated at this state)."""
        return window_cost(self.problem(rig=self.solved_rig()))

    def wheel_covariance(self) -> FloatArray | None:
        """The marginal covariance of the wheel calibration at the current state (the window's graph
        linearised once, ``gtsam.Marginals``), also kept in ``wheel.covariance``; None without wheel
        odometry or with fewer than two keyframes."""
        if self.wheel is None or len(self.keyframes) < 2:
            return None
        graph, values, _ = build_graph(self.problem(rig=self.solved_rig()))
        try:
            cov = np.asarray(gtsam.Marginals(graph, values).marginalCovariance(calibration_key()), dtype=float)
        except RuntimeError:  # indeterminate: nothing to say
            return None
        self.wheel.covariance = 0.5 * (cov + cov.T)
        return self.wheel.covariance

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
        if self.rig is None or len(self.keyframes) < 2 or self.config.backend != "lm":
            return None
        targets = visible_targets(self.camera, self.keyframes, self.config)
        if not any(targets):
            return None
        graph, values, _ = build_graph(self.problem(targets, RigVariable(self.rig.offset)))
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
        assert self.rig is not None
        return self.rig.offset + step, np.sqrt(np.maximum(np.diag(cov), 0.0))

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
        if not any(targets) and not (self.wheel and self.wheel.factors(self.keyframes, lambda kf: 0)):
            # the wheels alone may hold it
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

    def remove_oldest(self, window: SolvableWindow) -> WindowKeyframe:
        """Marginalise the oldest keyframe into :attr:`marginal` (or drop it, ``marginalize=False``)."""
        if window.config.marginalize:
            self.marginal = marginalize(window.problem(rig=window.solved_rig()), 0)
        kf = window.keyframes.pop(0)
        residual_memo.forget(kf.image)  # its residuals are not needed again
        return kf

    def optimize(self, window: SolvableWindow, targets: list[list[int]],
                 solver: WindowSolverName) -> WindowResult:
        """Solve the window with ``solver`` ("gtsam" or "handrolled"); keyframes updated in place."""
        solve = {"gtsam": solve_gtsam, "handrolled": solve_handrolled}.get(solver)
        if solve is None:
            raise InputError(f"unknown window solver {solver!r}: use 'gtsam' or 'handrolled'")
        wheel = window.wheel
        if wheel is not None:  # the wheel calibration: each solve starts from the last estimate and updates it
            solve = _updating_wheel(solve, wheel)
        imu = getattr(window, "imu", None)
        if imu is not None:  # the keyframes' velocities and biases: each solve starts from the last estimates
            solve = _updating_imu(solve, imu)
        rig = window.rig
        # the rig offset (gtvo.window.rig; docs/window.md, "Rig calibration"): none while rectified
        # (tested as a whole); else delta_x, which trades against the scale, is held at its start
        # value until the first full window (a corrected delta_y) or until a full window's data put
        # it clearly away from it (the marginalisation prior never holds the hold)
        solved = None if rig is None else rig.solved_offset
        hold = None if rig is None else rig.hold_x

        def problem(offset: FloatArray | None, hold_x: float | None) -> WindowProblem:
            return window.problem(targets, None if offset is None else RigVariable(offset, hold_x))

        res = solve(problem(solved, hold))
        full = self.marginal is not None or len(window.keyframes) >= window.config.size
        if rig is not None and solved is None:  # rectified: the offset as a whole is tested
            if full and rig.test_release_both(window.config.size, window.rig_free_estimate):
                res = solve(problem(rig.offset, None))
                assert res.rig_offset is not None
                rig.offset = res.rig_offset.copy()
            return res
        if rig is None or res.rig_offset is None:
            return res
        rig.offset = res.rig_offset.copy()
        if hold is not None and full and rig.test_release(window.config.size, window.rig_x_free_estimate):
            # solved again with delta_x free, from the held state (LM's damping, not the test's
            # linear step, decides how far it goes along the flat scale direction)
            res = solve(problem(rig.offset, None))
            assert res.rig_offset is not None
            rig.offset = res.rig_offset.copy()
        return res


def _updating_imu(solve, imu: ImuWindow):
    """``solve`` that writes the solved velocities and biases back to ``imu``."""
    def run(problem: WindowProblem) -> WindowResult:
        res = solve(problem)
        if res.variables is not None:
            imu.update(res.variables, problem.keyframes)
        return res
    return run


def _updating_wheel(solve, wheel: WheelCalibration):
    """``solve`` that writes the optimised calibration back to ``wheel.estimate``."""
    def run(problem: WindowProblem) -> WindowResult:
        res = solve(problem)
        if res.wheel_calibration is not None:
            wheel.estimate = res.wheel_calibration.copy()
        return res
    return run
