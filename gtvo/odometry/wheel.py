"""The odometry's side of the wheels: the calibration's settings from the run's ``wheel:`` section,
and what ``report.json`` says about it (docs/window.md, "Wheel odometry").

The calibration itself lives in :class:`gtvo.window.wheel.WheelCalibration`
(``VisualOdometry.wheel``): the window estimates it, :meth:`VisualOdometry._reinitialise` carries
a frame the images cannot place by it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import gtsam
import numpy as np
from numpy.typing import ArrayLike

from gtvo.config.sections.wheel import WheelConfig
from gtvo.datasets.wheel import WheelOdometry
from gtvo.errors import InputError
from factors.wheel_odometry import DIFF_DRIVE_NAMES
from gtvo.window.wheel import WheelCalibration, WheelSettings

if TYPE_CHECKING:
    from gtvo.odometry.window_port import WindowPort


def wheel_calibration(config: WheelConfig, log: WheelOdometry) -> WheelCalibration:
    """The calibration of ``log`` with the settings of ``config`` (``T_base_cam``: the log's own
    ``base_to_camera`` when it has one, a bag's ``/tf_static``, else the config's)."""
    T_bc = config.T_base_cam if log.base_to_camera is None else log.base_to_camera
    b0 = config.nominal_baseline if log.nominal_baseline is None else log.nominal_baseline
    settings = WheelSettings(model=config.model, T_base_cam=gtsam.Pose3(T_bc), nominal_baseline=float(b0),
                             prior_mean=config.calibration_prior, prior_sigma=config.calibration_prior_sigma,
                             translation_sigma=config.translation_sigma, rotation_sigma=config.rotation_sigma,
                             per_metre=config.sigma_per_metre, planar_rotation_sigma=config.planar_rotation_sigma,
                             planar_height_sigma=config.planar_height_sigma)
    return WheelCalibration(settings, log)


def wheel_report(wheel: WheelCalibration | None, window: WindowPort | None) -> dict[str, Any]:
    """``{"wheel_calibration": ...}`` (:meth:`gtvo.window.wheel.WheelCalibration.report` at the final
    ``window``'s marginal covariance) when the run had wheel odometry (``wheel``), else nothing."""
    if wheel is None:
        return {}
    if window is not None and window.wheel is not None:
        window.wheel_covariance()
    return {"wheel_calibration": wheel.report()}


def wheel_coverage_warning(log: WheelOdometry, frame_times: ArrayLike) -> str | None:
    """The line a run prints when ``log`` covers only part of the frames' times (the keyframes
    outside get no wheel factor and are not carried through blindness), None when it covers them all.

    Raises:
        InputError: ``log`` overlaps none of the frames (its times are in another clock), naming its source.
    """
    t = np.asarray(frame_times, dtype=np.float64).reshape(-1)
    if t.size == 0:
        return None
    a, b, t0, t1 = float(log.times[0]), float(log.times[-1]), float(t.min()), float(t.max())
    span = f"{a:.3f}..{b:.3f} s"
    if b < t0 or a > t1:
        raise InputError(f"the wheel odometry's times {span} do not overlap the frames' {t0:.3f}..{t1:.3f} s: "
                         "its times must be in the sequence's clock (seconds)", log.source)
    inside = int(np.count_nonzero((t >= a) & (t <= b)))
    if inside == t.size:
        return None
    return (f"the wheel odometry ({log.source}) covers {span}, {inside} of the {t.size} frames "
            f"({t0:.3f}..{t1:.3f} s): keyframes outside it get no wheel factor and are not carried by the wheels")


def wheel_calibration_line(calibration: dict[str, Any]) -> str:
    """report.json's ``wheel_calibration`` in one line: the model and each parameter's estimate with
    its marginal sigma (``(prior)`` when the run did not observe it; none when the window did not
    estimate it), e.g.
    ``wheel calibration (diff_drive, w.csv): left_wheel_scale 1.0200 +- 0.0062, ..., track_width_scale 1 +- 0.1 (prior)``."""
    if calibration["model"] == "linear":
        names = [f"X{i // 3 + 1}{i % 3 + 1}" for i in range(9)]
        values = list(calibration["X"])
    else:
        names = list(DIFF_DRIVE_NAMES)
        values = [calibration[n] for n in names]
    sigmas = calibration.get("sigmas") or [None] * len(values)
    observed = calibration.get("observed") or [True] * len(values)
    parts = [f"{n} {v:.4f}" + ("" if s is None else f" +- {s:.4f}") + ("" if o else " (prior)")
             for n, v, s, o in zip(names, values, sigmas, observed)]
    unestimated = "" if calibration.get("sigmas") is not None else " (not estimated: track mode or the fixed-lag back end)"
    source = f", {calibration['source']}" if calibration.get("source") else ""
    return f"wheel calibration ({calibration['model']}{source}): " + ", ".join(parts) + unestimated
