"""A run's keyframe pose covariances: ``covariances.npz``, the ``report.json`` summary and the
position ellipses of ``trajectory.png`` (docs/window.md, "Pose covariances").

``covariances.npz`` holds::

    frame_index   (K,)      int64    the keyframes' frame indices (as in trajectory.tum's order)
    timestamp     (K,)      float64  their timestamps (s)
    covariance    (K, 6, 6) float64  each keyframe's pose covariance
    tangent_order ()        str      "rx, ry, rz, tx, ty, tz (...)": GTSAM's Pose3 tangent order
    frame         ()        str      the perturbation and frame (right: T = T_hat * Exp(xi), body frame)
    source        ()        str      how they were computed (gtsam.Marginals, reduced Hessian, iSAM2)
    inflation     ()        float64  the factor the window's covariances were multiplied by (1: none)

Read it with ``np.load(path)`` (no pickle needed: the strings are NumPy unicode scalars). The
covariances as data and their summary: :mod:`gtvo.evaluation.covariances`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from gtvo.core.atomic import atomic_path
from gtvo.errors import InputError
from gtvo.evaluation.covariances import (TANGENT_FRAME, TANGENT_ORDER, CovarianceSummary, KeyframeCovariances,
                                         WrittenCovariances, covariance_summary, sigmas)
from gtvo.evaluation.trajectory import Trajectory

FloatArray = NDArray[np.float64]

#: Most position ellipses drawn in trajectory.png (evenly spaced keyframes).
MAX_ELLIPSES = 20

__all__ = ["MAX_ELLIPSES", "TANGENT_FRAME", "TANGENT_ORDER", "CovarianceSummary", "KeyframeCovariances",
           "WrittenCovariances", "covariance_summary", "position_ellipses", "read_covariances", "sigmas",
           "write_covariances"]


def write_covariances(path: str | Path, cov: KeyframeCovariances) -> Path:
    """Write ``covariances.npz`` atomically."""
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **cov.arrays())
    return Path(path)


def read_covariances(path: str | Path) -> KeyframeCovariances:
    """Read a ``covariances.npz`` written by :func:`write_covariances`."""
    try:
        with np.load(path) as z:
            return KeyframeCovariances(z["frame_index"], z["timestamp"], z["covariance"], str(z["source"]),
                                       float(z["inflation"]))
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"not a covariances file: {exc}", path=path) from exc


def position_ellipses(cov: KeyframeCovariances, traj: Trajectory, most: int = MAX_ELLIPSES
                      ) -> tuple[FloatArray, FloatArray]:
    """Centres (M, 3) and world-frame position covariances (M, 3, 3) of up to ``most`` evenly spaced
    keyframes found in ``traj`` (by timestamp; ``traj`` may be aligned to ground truth: its rotations
    carry the body-frame blocks into its world, ``R P_tt R^T``)."""
    if not len(traj) or not len(cov):
        return np.zeros((0, 3)), np.zeros((0, 3, 3))
    idx = np.clip(np.searchsorted(traj.timestamps, cov.timestamp), 0, len(traj) - 1)
    found = np.isclose(traj.timestamps[idx], cov.timestamp) & np.all(np.isfinite(cov.covariance), axis=(1, 2))
    ok = np.flatnonzero(found)
    ok = ok[ok > 0] if len(ok) > 1 else ok  # the gauge keyframe has no extent
    if len(ok) > most:
        ok = ok[np.unique(np.linspace(0, len(ok) - 1, most).round().astype(int))]
    R = traj.poses[idx[ok], :3, :3]
    P = cov.covariance[ok, 3:, 3:]
    return traj.positions[idx[ok]], np.einsum("kij,kjl,kml->kim", R, P, R)
