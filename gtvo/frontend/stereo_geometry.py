"""The geometry of a stereo match: the epipolar direction of a host pixel (:func:`epipolar_direction`)
and the LSD-SLAM variance of a disparity along it (:func:`disparity_variance`); the search that
uses them: :mod:`gtvo.frontend.stereo_depth` (stages 1 and 4 of its module docstring)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def epipolar_direction(bearing: ArrayLike, translation: ArrayLike) -> FloatArray:
    """Unit epipolar direction in the target image, the notes' ``(epx, epy)``, (N, 2).

    ``(epx, epy) = (-a t3 + t1, -b t3 + t2)`` where ``(a, b, 1)`` is the (rotated) bearing of the
    host pixel and ``t = (t1, t2, t3)`` the translation of ``T_target_host``: the direction in
    which the projection moves as the inverse depth grows. For a rectified pair
    (``t = (-baseline, 0, 0)``) it is ``(-1, 0)`` for every pixel: the search runs along the row.
    Rows whose direction vanishes (pure forward motion at the epipole) are returned as 0.
    """
    b = np.asarray(bearing, dtype=float).reshape(-1, 3)
    b = b / b[:, 2:3]
    t = np.asarray(translation, dtype=float).reshape(3)
    ep = np.column_stack([-b[:, 0] * t[2] + t[0], -b[:, 1] * t[2] + t[1]])
    n = np.linalg.norm(ep, axis=1, keepdims=True)
    return np.divide(ep, n, out=np.zeros_like(ep), where=n > 0)


def disparity_variance(gx: ArrayLike, gy: ArrayLike, line: ArrayLike, sigma_intensity: float,
                       sigma_line: float) -> FloatArray:
    """LSD-SLAM disparity variance ``sigma_disp^2`` (px^2) of N points from their pattern gradients.

    Args:
        gx, gy: (N, P) host-image gradients at the P pattern pixels (grey levels per px).
        line: (N, 2) unit epipolar directions ``l`` (:func:`epipolar_direction`).
        sigma_intensity: image noise ``sigma_I`` (grey levels).
        sigma_line: epipolar-line position error ``sigma_l`` (px).

    Returns:
        ``sigma_l^2 * g2 / g_ll + 2 sigma_I^2 / g_ll`` with ``g_ll = mean_k (g_k . l)^2`` and
        ``g2 = mean_k |g_k|^2``: the geometric error ``sigma_l^2 / <g/|g|, l>^2`` plus the
        photometric error ``2 sigma_I^2 / g_p^2`` (``g_p`` the gradient along the line), both
        with pattern-averaged squared gradients. ``inf`` where ``g_ll`` is 0.
    """
    gx = np.atleast_2d(np.asarray(gx, dtype=float))
    gy = np.atleast_2d(np.asarray(gy, dtype=float))
    ln = np.asarray(line, dtype=float).reshape(-1, 2)
    g_l = gx * ln[:, :1] + gy * ln[:, 1:]
    g_ll = np.mean(g_l * g_l, axis=1)
    g2 = np.mean(gx * gx + gy * gy, axis=1)
    safe = g_ll > 1e-12
    g_ll_s = np.where(safe, g_ll, 1.0)
    return np.where(safe, (sigma_line ** 2) * g2 / g_ll_s + 2.0 * sigma_intensity ** 2 / g_ll_s, np.inf)
