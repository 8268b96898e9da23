"""Residual math of gtvo as GTSAM factors with analytic Jacobians.

This package holds the residuals and their Jacobians and nothing else: no file I/O, no
pipeline state. Every factor works in a plain ``gtsam.NonlinearFactorGraph``.

* :mod:`factors.photometric`: the kernel (warp, residuals, Jacobians, masks, weights, Gauss-Newton
  sums); its hot loops are compiled in :mod:`factors._compiled` (numba).
* :mod:`factors.gtsam_factors`: ``PhotometricFactor``, ``StereoFactor``,
  ``InverseDepthSmoothnessFactor``, ``MotionSmoothnessFactor``, ``ConstantVelocityFactor``,
  ``PhotometricBatchFactor``, and
  ``PythonFactor``, their base (a ``CustomFactor`` that GTSAM can free; docs/factors.md §8).
* :mod:`factors.smart`: ``HostPointsFactor``, the per-host factor with Schur-eliminated depths.

Derivations: docs/factors.md.
"""

from factors.gtsam_factors import (ConstantVelocityFactor, InverseDepthSmoothnessFactor, MotionSmoothnessFactor,
                                   PhotometricBatchFactor, PhotometricFactor, PythonFactor, StereoFactor,
                                   edge_aware_weight)
from factors.photometric import PATTERN_DSO8, GradientImage, photometric_residuals, stereo_residuals
from factors.smart import HostPointsFactor

__all__ = [
    "ConstantVelocityFactor", "GradientImage", "HostPointsFactor", "InverseDepthSmoothnessFactor",
    "MotionSmoothnessFactor", "PATTERN_DSO8", "PhotometricBatchFactor", "PhotometricFactor", "PythonFactor",
    "StereoFactor", "edge_aware_weight", "photometric_residuals", "stereo_residuals",
]
