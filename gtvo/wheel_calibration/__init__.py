"""Odometry calibration: find how raw odometry motions map to reference motions.

* Linear model (the notes on estimation and odometry calibration, section 3): ``u' = X u`` with a 3x3 X by least squares
  (:func:`fit_linear`, hand-rolled normal equations; :func:`fit_linear_gtsam`, the same with GTSAM
  custom factors, LM and Marginals).
* Differential-drive model: wheel scales and baseline scale (:func:`fit_diff_drive`,
  :func:`fit_diff_drive_gtsam`).
* Joint calibration inside a Pose2 graph: :func:`joint_calibration`.
* Degenerate data raises :class:`gtvo.errors.InputError` naming the unobservable parameters.

Math modules do no I/O; readers are in :mod:`gtvo.wheel_calibration.io`, the plot in
:mod:`gtvo.wheel_calibration.plot`. Details: docs/odometry_calibration.md.
"""

from numpy.typing import ArrayLike

from gtvo.errors import InputError
from gtvo.wheel_calibration.diff_drive import DiffDriveCalibration, apply_diff_drive, fit_diff_drive
from gtvo.wheel_calibration.gtsam_solvers import (JointCalibrationResult, LoopClosure, PosePrior, fit_diff_drive_gtsam,
                                                 fit_linear_gtsam, joint_calibration)
from gtvo.wheel_calibration.io import read_motion_pair, read_motions
from gtvo.wheel_calibration.linear import LinearCalibration, ResidualStatistics, apply_linear, fit_linear
from gtvo.wheel_calibration.motions import integrate_motions, position_rmse, relative_motions
from gtvo.wheel_calibration.observability import Observability

__all__ = [
    "DiffDriveCalibration", "JointCalibrationResult", "LinearCalibration", "LoopClosure", "Observability",
    "PosePrior", "ResidualStatistics", "apply_diff_drive", "apply_linear", "fit_diff_drive", "fit_diff_drive_gtsam",
    "fit_linear", "fit_linear_gtsam", "integrate_motions", "joint_calibration", "position_rmse", "read_motion_pair",
    "read_motions", "relative_motions", "calibrate",
]


def calibrate(odom: ArrayLike, reference: ArrayLike, model: str = "linear", solver: str = "handrolled",
              nominal_baseline: float = 1.0) -> LinearCalibration | DiffDriveCalibration:
    """Fit ``reference ~ f(odom)``: ``model`` in {"linear", "diff-drive"}, ``solver`` in {"handrolled", "gtsam"}.

    ``nominal_baseline`` (m) is used by the diff-drive model only. Raises InputError for bad or
    degenerate input (naming the unobservable parameters) and for an unknown model/solver.
    """
    fits = {("linear", "handrolled"): lambda: fit_linear(odom, reference),
            ("linear", "gtsam"): lambda: fit_linear_gtsam(odom, reference),
            ("diff-drive", "handrolled"): lambda: fit_diff_drive(odom, reference, nominal_baseline),
            ("diff-drive", "gtsam"): lambda: fit_diff_drive_gtsam(odom, reference, nominal_baseline)}
    if (model, solver) not in fits:
        raise InputError(f"unknown model/solver {model!r}/{solver!r} (models: linear, diff-drive; "
                         "solvers: handrolled, gtsam)")
    return fits[(model, solver)]()
