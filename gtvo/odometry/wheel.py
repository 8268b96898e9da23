"""The odometry's side of the wheels: the calibration's settings from the run's ``wheel:`` section,
and what ``report.json`` says about it (docs/window.md, "Wheel odometry").

The calibration itself lives in :class:`gtvo.window.wheel.WheelCalibration`
(``VisualOdometry.wheel``): the window estimates it, :meth:`VisualOdometry._reinitialise` carries
a frame the images cannot place by it.
"""

from __future__ import annotations

from typing import Any

import gtsam

from gtvo.config.wheel import WheelConfig
from gtvo.datasets.wheel import WheelOdometry
from gtvo.window import SlidingWindowOptimizer
from gtvo.window.wheel import WheelCalibration, WheelSettings


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


def wheel_report(wheel: WheelCalibration | None, window: SlidingWindowOptimizer | None) -> dict[str, Any]:
    """``{"wheel_calibration": ...}`` (:meth:`gtvo.window.wheel.WheelCalibration.report` at the final
    ``window``'s marginal covariance) when the run had wheel odometry (``wheel``), else nothing."""
    if wheel is None:
        return {}
    if window is not None and window.wheel is not None:
        window.wheel_covariance()
    return {"wheel_calibration": wheel.report()}
