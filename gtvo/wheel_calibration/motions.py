"""Planar relative motions ``u = (dx, dy, dtheta)`` and the trajectories they integrate to.

Pure numpy, no I/O. A motion is expressed in the robot frame of the pose it starts from:
``x_{i+1} = x_i (+) u_i`` with ``(+)`` the SE(2) composition, i.e. the same as
``gtsam.Pose2(x_i).compose(gtsam.Pose2(*u_i))``. Poses are rows ``(x, y, theta)`` in the world frame.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.errors import InputError

MOTION_COMPONENTS: tuple[str, str, str] = ("dx", "dy", "dtheta")


def as_motions(motions: ArrayLike, name: str = "motions") -> NDArray[np.float64]:
    """``motions`` as an (N, 3) float64 array; InputError naming ``name`` and the first bad row otherwise."""
    u = np.asarray(motions, dtype=np.float64)
    if u.ndim != 2 or u.shape[1] != 3:
        raise InputError(f"{name}: expected an (N, 3) array of dx dy dtheta, got shape {u.shape}")
    bad = ~np.isfinite(u).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{name}: row {i} is not finite ({u[i].tolist()}); "
                         f"{int(bad.sum())} non-finite row(s) in all")
    return u


def wrap_angle(theta: ArrayLike) -> NDArray[np.float64]:
    """Angles wrapped to [-pi, pi)."""
    t = np.asarray(theta, dtype=np.float64)
    return (t + np.pi) % (2.0 * np.pi) - np.pi


def integrate_motions(motions: ArrayLike, start: ArrayLike = (0.0, 0.0, 0.0)) -> NDArray[np.float64]:
    """Compose the motions from ``start``: an (N+1, 3) array of poses ``(x, y, theta)``, headings unwrapped.

    Vectorised: heading_k = theta0 + cumsum(dtheta), positions = cumsum of R(heading_{k-1}) [dx, dy].
    """
    u = as_motions(motions)
    x0 = np.asarray(start, dtype=np.float64).reshape(3)
    heading = x0[2] + np.concatenate([[0.0], np.cumsum(u[:, 2])])
    c, s = np.cos(heading[:-1]), np.sin(heading[:-1])
    step = np.stack([c * u[:, 0] - s * u[:, 1], s * u[:, 0] + c * u[:, 1]], axis=1)
    xy = x0[:2] + np.concatenate([np.zeros((1, 2)), np.cumsum(step, axis=0)])
    return np.column_stack([xy, heading])


def relative_motions(poses: ArrayLike) -> NDArray[np.float64]:
    """The inverse of :func:`integrate_motions`: motions ``u_i = x_i^-1 x_{i+1}`` of an (N+1, 3) pose array."""
    p = np.asarray(poses, dtype=np.float64)
    d = np.diff(p[:, :2], axis=0)
    c, s = np.cos(p[:-1, 2]), np.sin(p[:-1, 2])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1],
                            wrap_angle(np.diff(p[:, 2]))])


def rigid_align_2d(source_xy: ArrayLike, target_xy: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares rotation R (2x2, det +1) and translation t with ``R @ source + t ~ target`` (Umeyama, no scale)."""
    a = np.asarray(source_xy, dtype=np.float64)
    b = np.asarray(target_xy, dtype=np.float64)
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((b - mb).T @ (a - ma))
    d = np.diag([1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    r = u @ d @ vt
    return r, mb - r @ ma


def position_rmse(estimate: ArrayLike, ground_truth: ArrayLike, align: bool = True) -> float:
    """RMS position error (m) between two (N, >=2) trajectories, after a rigid 2-D alignment if ``align``.

    With ``align=False`` the trajectories are compared as they are (both should start from the same pose).
    """
    est = np.asarray(estimate, dtype=np.float64)[:, :2]
    gt = np.asarray(ground_truth, dtype=np.float64)[:, :2]
    if est.shape != gt.shape:
        raise InputError(f"trajectories differ in length: {est.shape[0]} vs {gt.shape[0]} poses")
    if align:
        r, t = rigid_align_2d(est, gt)
        est = est @ r.T + t
    return float(np.sqrt(np.mean(np.sum((est - gt) ** 2, axis=1))))
