"""The weights of a photometric residual: the variance weight ``W`` and the Huber kernel.

The residual depends on the uncertain inverse depth, so its variance is
``2 sigma_I^2 + (dr/dd)^2 V`` (noise in both images plus the depth's, first order) and its
weight ``W`` the inverse (:func:`variance_weight`). The robust kernel is Huber on one point's
whitened pattern norm ``|e_n| = sqrt(sum_P W r^2)``: :func:`point_robust_terms` gives each point's
IRLS weight and loss (docs/factors.md §4).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors import _compiled_sums
from gtvo.errors import InputError

FloatArray = NDArray[np.float64]


def variance_weight(J_depth: ArrayLike, inverse_depth_variance: ArrayLike, sigma_intensity: float) -> FloatArray:
    """The notes' weight ``W = (2 sigma_I^2 + (dr/dd)^2 V)^-1`` per residual.

    Args:
        J_depth: (N, P) dr/dd.
        inverse_depth_variance: (N,) V of each point (0: depth known exactly).
        sigma_intensity: intensity noise sigma_I (8-bit units); both images carry it, hence 2.
    """
    Jd = np.asarray(J_depth, dtype=float)
    V = np.asarray(inverse_depth_variance, dtype=float).reshape(-1, *([1] * (Jd.ndim - 1)))
    return 1.0 / (2.0 * sigma_intensity ** 2 + Jd * Jd * V)


def huber_weight(norm: ArrayLike, k: float) -> FloatArray:
    """IRLS weight of the Huber kernel on a whitened norm: 1 inside ``k``, ``k/|x|`` outside."""
    x = np.abs(np.asarray(norm, dtype=float))
    return np.where(x <= k, 1.0, k / np.maximum(x, k))  # (max: no overflow in the unused branch)


def huber_loss(norm: ArrayLike, k: float) -> FloatArray:
    """Huber loss ``rho(x)``: ``x^2/2`` inside ``k``, ``k|x| - k^2/2`` outside (GTSAM's)."""
    x = np.abs(np.asarray(norm, dtype=float))
    return np.where(x <= k, 0.5 * x * x, k * x - 0.5 * k * k)


def point_robust_terms(weight: ArrayLike, residual: ArrayLike, k: float | None) -> tuple[FloatArray, FloatArray]:
    """Each point's Huber IRLS weight and loss on its whitened pattern norm.

    With ``x_n = sqrt(sum_P W r^2)`` over the point's pattern residuals (``weight`` W and
    ``residual`` of shape (N, P)): ``(huber_weight(x, k), huber_loss(x, k))``, each (N,); ``k``
    None: no kernel, ``(1, x^2 / 2)``. One compiled pass (the window calls it per host and target
    at every cost evaluation).
    """
    W = np.ascontiguousarray(weight, dtype=float)
    r = np.ascontiguousarray(residual, dtype=float)
    if W.shape != r.shape or r.ndim != 2:
        raise InputError(f"point_robust_terms: weight {W.shape} and residual {r.shape} must be equal (N, P)")
    return _compiled_sums.point_huber(W, r, 0.0 if k is None else float(k), k is not None)

