"""Residual math of gtvo as GTSAM factors with analytic Jacobians.

This package holds the residuals and their Jacobians and nothing else: no file I/O, no
pipeline state. Every factor works in a plain ``gtsam.NonlinearFactorGraph``.

* :mod:`factors.photometric`: the kernel (pattern, image sampling, warp, residuals, Jacobians,
  masks); its hot loops are compiled in :mod:`factors._compiled` (numba).
* :mod:`factors.weights`: the variance weight ``W`` and the Huber kernel.
* :mod:`factors.host_points`: ``HostPoints``, one host keyframe's points linearised with their
  depths Schur-eliminated (pure numpy; both window solvers use it), and the Gauss-Newton sums.
* :mod:`factors.gtsam_factors`: ``PhotometricFactor``, ``StereoFactor``, ``PhotometricBatchFactor``,
  and ``PythonFactor``, the base of every Python factor (a ``CustomFactor`` that GTSAM can free;
  docs/factors.md §8).
* :mod:`factors.smoothness`: ``InverseDepthSmoothnessFactor``, ``MotionSmoothnessFactor``,
  ``ConstantVelocityFactor``.
* :mod:`factors.smart`: ``HostPointsFactor``, the per-host factor with Schur-eliminated depths
  (the GTSAM adapter of ``HostPoints``).
* :mod:`gtvo.core.keys`: the GTSAM keys of the VO problem; :mod:`factors.motion`,
  :mod:`factors.odometry_calibration`: the motion model's and the wheel-odometry calibration's factors.

Derivations: docs/factors.md.
"""

from factors.gtsam_factors import PhotometricBatchFactor, PhotometricFactor, PythonFactor, StereoFactor
from factors.host_points import HostPoints
from factors.photometric import PATTERN_DSO8, GradientImage, photometric_residuals, stereo_residuals
from factors.smart import HostPointsFactor
from factors.smoothness import (ConstantVelocityFactor, InverseDepthSmoothnessFactor, MotionSmoothnessFactor,
                                edge_aware_weight)

__all__ = [
    "ConstantVelocityFactor", "GradientImage", "HostPoints", "HostPointsFactor", "InverseDepthSmoothnessFactor",
    "MotionSmoothnessFactor", "PATTERN_DSO8", "PhotometricBatchFactor", "PhotometricFactor", "PythonFactor",
    "StereoFactor", "edge_aware_weight", "photometric_residuals", "stereo_residuals",
]
