"""The wheel odometry's calibration as a window variable: one home for its estimate, its prior, its
factors and its report (docs/window.md, "Wheel odometry").

With wheel odometry the window gets a :class:`factors.wheel_odometry.WheelOdometryFactor` between
every two consecutive keyframes whose times the wheel log covers, on their poses and the
calibration variable (:func:`gtvo.core.keys.calibration_key`; the notes' linear X, 9 entries
row-major, or the diff-drive ``(k_L, k_R, k_b)``). The calibration is carried from window to window
through the marginalisation prior, like the rig offset: its prior (mean and sigma from the
configuration) is set once, with the gauge prior; afterwards the marginalisation prior carries
what the leaving keyframes said about it. :class:`WheelCalibration` owns the estimate: the window
updates it after every optimisation, the odometry reads it to carry a frame through blindness
(:meth:`WheelCalibration.predict`) and the report reads :meth:`WheelCalibration.report`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Protocol, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.wheel_odometry import (CALIBRATION_SIZE, DIFF_DRIVE_NAMES, WheelOdometryFactor, calibrated_motion,
                                    nominal_calibration, planar_pose, wheel_step_sigmas)
from gtvo.core.keys import calibration_key, pose_key
from gtvo.errors import InputError

from gtvo.config.sections.wheel import WheelConfig  # the defaults of the settings

FloatArray = NDArray[np.float64]

#: A parameter is reported "observed" when its marginal sigma is below this fraction of its prior sigma.
OBSERVED_FRACTION = 0.5
#: The warning line: a diff-drive scale this far from 1, or an entry of X this far from I ...
WARN_FROM_NOMINAL = 0.05
#: ... and this many marginal sigmas from it.
WARN_SIGMAS = 3.0


class WheelLog(Protocol):
    """What the window reads of a wheel log (:class:`gtvo.datasets.wheel.WheelOdometry`)."""

    def covers(self, t0: float, t1: float) -> bool:
        """Whether the log covers the interval ``[t0, t1]``."""

    def between(self, t0: float, t1: float) -> FloatArray:
        """The raw planar motion ``(dx, dy, dtheta)`` of the base from ``t0`` to ``t1``."""


@dataclass(frozen=True)
class WheelSettings:
    """The wheel factors' settings (the run's ``wheel:`` section, docs/configuration.md).

    Attributes:
        T_base_cam: the camera's pose in the base frame (REP 103 base: x forward, y left, z up; the
            config's ``wheel.base_to_camera``, or a bag's ``/tf_static``).
        model: ``"diff_drive"`` (``k_L, k_R, k_b``) or ``"linear"`` (the notes' 3x3 X).
        nominal_baseline: the diff-drive model's nominal track width ``b0`` (m).
        prior_mean: the calibration's prior mean (None: nominal, X = I or all scales 1).
        prior_sigma: the prior's sigma of every parameter (a scale, or an entry of X).
        translation_sigma, rotation_sigma, per_metre, planar_rotation_sigma, planar_height_sigma:
            the factor's sigmas (:func:`factors.wheel_odometry.wheel_step_sigmas`).
    """

    T_base_cam: gtsam.Pose3
    model: str = "diff_drive"
    nominal_baseline: float = 1.0
    prior_mean: tuple[float, ...] | None = None
    prior_sigma: float = WheelConfig.calibration_prior_sigma  # the defaults of the config's wheel section
    translation_sigma: float = WheelConfig.translation_sigma
    rotation_sigma: float = WheelConfig.rotation_sigma
    per_metre: float = WheelConfig.sigma_per_metre
    planar_rotation_sigma: float = WheelConfig.planar_rotation_sigma
    planar_height_sigma: float = WheelConfig.planar_height_sigma

    @property
    def size(self) -> int:
        """Number of calibration parameters."""
        return CALIBRATION_SIZE[self.model]

    def mean(self) -> FloatArray:
        """The prior mean as a vector (checked)."""
        nominal = nominal_calibration(self.model)
        if self.prior_mean is None:
            return nominal
        mean = np.asarray(self.prior_mean, dtype=float).reshape(-1)
        if mean.shape != nominal.shape or not np.all(np.isfinite(mean)):
            raise InputError(f"wheel calibration prior: the {self.model} model has {nominal.size} finite "
                             f"parameters, got {list(self.prior_mean)}")
        return mean


class WheelCalibration:
    """The calibration's estimate and the wheel log it calibrates (module docstring).

    Attributes:
        settings: the factors' settings.
        log: the wheel log.
        estimate: the current calibration vector, updated by the window.
        covariance: its marginal covariance at the last :meth:`gtvo.window.SlidingWindowOptimizer.wheel_covariance`
            (None before).
    """

    def __init__(self, settings: WheelSettings, log: WheelLog) -> None:
        self.settings = settings
        self.log = log
        self.estimate: FloatArray = settings.mean().copy()
        self.covariance: FloatArray | None = None
        self._raw: dict[tuple[float, float], FloatArray | None] = {}

    def window_state(self, indices: Sequence[int]) -> FloatArray:
        """What the front end reads of the calibration between window updates: the estimate (a
        window in a worker process hands it back with each update; ``indices``: its keyframes)."""
        return self.estimate.copy()

    def take_window_state(self, state: FloatArray) -> None:
        """Take the worker's :meth:`window_state` as this calibration's."""
        self.estimate = np.asarray(state, dtype=float).copy()

    @property
    def size(self) -> int:
        """Number of calibration parameters."""
        return self.settings.size

    def raw_motion(self, t0: float | None, t1: float | None) -> FloatArray | None:
        """The wheels' raw motion from ``t0`` to ``t1``, None when a time is missing or the log does
        not cover the interval (read once per interval)."""
        if t0 is None or t1 is None or not t1 > t0:
            return None
        key = (float(t0), float(t1))
        if key not in self._raw:
            self._raw[key] = (np.asarray(self.log.between(t0, t1), dtype=float).reshape(3)
                              if self.log.covers(t0, t1) else None)
        return self._raw[key]

    def factors(self, keyframes: Sequence[Any], pose_key_of: Callable[[Any], int]
                ) -> list[tuple[int, WheelOdometryFactor]]:
        """``(k, factor)`` between every two consecutive keyframes ``k, k+1`` (positions; anything with
        a ``timestamp``, None for none) with times the log covers; ``pose_key_of(keyframe)``: its pose key."""
        s = self.settings
        out = []
        for k in range(len(keyframes) - 1):
            a, b = keyframes[k], keyframes[k + 1]
            u = self.raw_motion(a.timestamp, b.timestamp)
            if u is None:
                continue
            sig = wheel_step_sigmas(u, s.translation_sigma, s.rotation_sigma, s.per_metre,
                                    s.planar_rotation_sigma, s.planar_height_sigma)
            out.append((k, WheelOdometryFactor(pose_key_of(a), pose_key_of(b), calibration_key(), u, s.model,
                                               s.T_base_cam, sig, s.nominal_baseline)))
        return out

    def add_to(self, problem: Any) -> None:
        """The wheels in a window problem (:class:`gtvo.window.problem.WindowSensor`): the
        calibration variable at :attr:`estimate`, the factors between consecutive keyframes
        (:meth:`factors`) and, until the problem's marginalisation prior carries the calibration,
        its prior (:meth:`prior_factor`)."""
        problem.variables.insert(calibration_key(), np.asarray(self.estimate, dtype=float).copy())
        for _, f in self.factors(problem.keyframes, lambda kf: pose_key(kf.index)):
            problem.factors.add(f)
        if problem.marginal is None or calibration_key() not in problem.marginal.keys:
            problem.factors.add(self.prior_factor())

    def prior_sigmas(self) -> FloatArray:
        """The prior's sigma of every parameter."""
        return np.full(self.size, float(self.settings.prior_sigma))

    def prior_factor(self) -> gtsam.PriorFactorVector:
        """The calibration's prior (set once: the marginalisation prior carries it afterwards)."""
        return gtsam.PriorFactorVector(calibration_key(), self.settings.mean(),
                                       gtsam.noiseModel.Diagonal.Sigmas(self.prior_sigmas()))

    def predict(self, T_world_cam: gtsam.Pose3, t0: float, t1: float) -> gtsam.Pose3 | None:
        """The camera's pose at ``t1`` carried from ``T_world_cam`` at ``t0`` by the calibrated wheel
        motion (``B_1 = B_0 Z(f(u; c))``, ``B = T T_base_cam^-1``); None when the log does not cover it."""
        u = self.raw_motion(t0, t1)
        if u is None:
            return None
        v, _ = calibrated_motion(self.settings.model, self.estimate, u, self.settings.nominal_baseline)
        T_bc = self.settings.T_base_cam
        return T_world_cam.compose(T_bc.inverse()).compose(planar_pose(v)).compose(T_bc)

    def report(self) -> dict[str, Any]:
        """``report.json``'s ``wheel_calibration`` (docs/evaluation.md): the model, the wheel log's
        source, the ``T_base_cam`` used (``[x, y, z, qx, qy, qz, qw]``: the config's or a bag's
        ``/tf_static``), the estimate
        (``X`` row-major, or the diff-drive parameters by name), the marginal sigmas (None before the
        window computed them), the prior's, per parameter whether the run observed it (sigma below
        :data:`OBSERVED_FRACTION` of the prior's) and the warning line (None: nothing to say)."""
        s = self.settings
        sigma = None if self.covariance is None else np.sqrt(np.maximum(np.diag(self.covariance), 0.0))
        prior = self.prior_sigmas()
        T_bc = s.T_base_cam
        q = T_bc.rotation().toQuaternion()
        out: dict[str, Any] = {"model": s.model, "source": getattr(self.log, "source", None),
                               "base_to_camera": [*(float(x) for x in T_bc.translation()),
                                                  float(q.x()), float(q.y()), float(q.z()), float(q.w())]}
        if s.model == "linear":
            out["X"] = [float(x) for x in self.estimate]
        else:
            out.update({name: float(x) for name, x in zip(DIFF_DRIVE_NAMES, self.estimate)})
            out["nominal_baseline_m"] = float(s.nominal_baseline)
            out["track_width_m"] = float(self.estimate[2] * s.nominal_baseline)
        out["sigmas"] = None if sigma is None else [float(x) for x in sigma]
        out["prior_sigmas"] = [float(x) for x in prior]
        out["observed"] = None if sigma is None else [bool(x < OBSERVED_FRACTION * p) for x, p in zip(sigma, prior)]
        out["warning"] = self.warning(sigma)
        return out

    def warning(self, sigma: FloatArray | None) -> str | None:
        """The line a run prints when the estimate is clearly far from nominal, else None."""
        if sigma is None:
            return None
        off = self.estimate - nominal_calibration(self.settings.model)
        names = (DIFF_DRIVE_NAMES if self.settings.model == "diff_drive"
                 else [f"X[{i // 3}][{i % 3}]" for i in range(9)])
        far = [f"{n} {x:.4g}" for n, x, d, sg in zip(names, self.estimate, off, sigma)
               if abs(d) > WARN_FROM_NOMINAL and abs(d) > WARN_SIGMAS * sg]
        if not far:
            return None
        return (f"the wheel odometry's calibration is far from nominal ({', '.join(far)}): "
                "check the wheel radii, the track width and the tick scale in the config")
