"""Geometric verification of a loop candidate: ORB matching, PnP RANSAC, LM refinement, and the
information matrix of the relative pose.

Names (docs/loop_closure.md): the query keyframe ``i`` sees keypoints ``x_k`` (pixels); the
candidate keyframe ``j`` has 3-D points ``X_k`` in its camera frame. PnP finds ``T_i_j`` with
``x_k ~ pi(T_i_j X_k)``, i.e. ``T_i_j = T_world_i^-1 T_world_j``, the pose of ``j`` in ``i``'s
camera frame (the measurement of ``gtsam.BetweenFactorPose3(x_i, x_j, T_i_j)``).

Pure math on arrays: no I/O, no keyframe database.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera
from gtvo.config.sections.loops import VerificationConfig
from gtvo.loops.features import hamming_distances

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PnPResult:
    """A verified relative pose.

    Attributes:
        T_i_j: 4x4 pose of keyframe j in keyframe i's camera frame.
        inliers: indices (into the matches given to :func:`verify_pnp`) of the inliers.
        n_matches: number of matches tried.
        rmse_px: reprojection RMSE of the inliers after refinement (pixels).
        information: 6x6 information of ``T_i_j`` in GTSAM's Pose3 tangent [rot, trans], right
            perturbation ``T_i_j * Exp(xi)``: ``inv(inv(Lambda) + floor)`` with Lambda from
            :func:`pose_information` and the covariance floor of :class:`VerificationConfig`.
    """

    T_i_j: FloatArray
    inliers: NDArray[np.int64]
    n_matches: int
    rmse_px: float
    information: FloatArray


def match_descriptors(query: NDArray[np.uint8], candidate: NDArray[np.uint8], ratio: float = 0.8,
                      max_hamming: float = 64.0) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Mutual-best ORB matches that pass the ratio test: ``(query_idx, candidate_idx)``.

    A query descriptor's best candidate must be closer than ``ratio`` times its second best and
    within ``max_hamming``, and the query descriptor must be that candidate's best too (cross check).
    """
    nq, nc = query.shape[0], candidate.shape[0]
    if nq == 0 or nc < 2:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    dist = hamming_distances(query, candidate)
    two = np.argpartition(dist, 1, axis=1)[:, :2]
    d2 = np.take_along_axis(dist, two, axis=1)
    order = np.argsort(d2, axis=1)
    best = np.take_along_axis(two, order[:, :1], axis=1)[:, 0]
    d_best = np.take_along_axis(d2, order[:, :1], axis=1)[:, 0]
    d_second = np.take_along_axis(d2, order[:, 1:], axis=1)[:, 0]
    back = np.argmin(dist, axis=0)
    q = np.arange(nq)
    ok = (d_best < ratio * d_second) & (d_best <= max_hamming) & (back[best] == q)
    return q[ok].astype(np.int64), best[ok].astype(np.int64)


def _skew(v: FloatArray) -> FloatArray:
    """(N, 3) -> (N, 3, 3) cross-product matrices."""
    z = np.zeros(v.shape[0])
    return np.stack([np.stack([z, -v[:, 2], v[:, 1]], 1), np.stack([v[:, 2], z, -v[:, 0]], 1),
                     np.stack([-v[:, 1], v[:, 0], z], 1)], 1)


def reprojection(T_i_j: FloatArray, points_j: FloatArray, camera: PinholeCamera) -> tuple[FloatArray, FloatArray]:
    """Pixels (N, 2) of points of frame j seen from frame i and their depths z_i (N,)."""
    q = points_j @ T_i_j[:3, :3].T + T_i_j[:3, 3]
    uv, _ = camera.project(q)
    return uv, q[:, 2]


def reprojection_jacobians(T_i_j: FloatArray, points_j: FloatArray,
                           camera: PinholeCamera) -> tuple[FloatArray, FloatArray]:
    """Jacobians of the projection ``pi(T_i_j Exp(xi) X)`` of points X (N, 3) of frame j.

    Returns ``(J_xi, J_X)``: (N, 2, 6) with respect to the right perturbation ``xi = [omega, v]``
    (GTSAM order) at ``xi = 0``, i.e. ``P R [-[X]x, I]``, and (N, 2, 3) with respect to X, ``P R``,
    where ``P = d pi / d q`` at ``q = T_i_j X`` and ``R`` is the rotation of ``T_i_j``.
    """
    R = T_i_j[:3, :3]
    q = points_j @ R.T + T_i_j[:3, 3]
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    n = q.shape[0]
    P = np.zeros((n, 2, 3))
    P[:, 0, 0] = camera.fx / z
    P[:, 0, 2] = -camera.fx * x / z**2
    P[:, 1, 1] = camera.fy / z
    P[:, 1, 2] = -camera.fy * y / z**2
    PR = P @ R
    return np.concatenate([-PR @ _skew(points_j), PR], axis=2), PR


def pose_information(T_i_j: FloatArray, points_j: FloatArray, point_covariances: FloatArray, uv_i: FloatArray,
                     pixel_sigmas: FloatArray, camera: PinholeCamera) -> tuple[FloatArray, float]:
    """Information (6x6, GTSAM order [rot, trans]) of the PnP pose and the variance factor.

    Residual ``r_k = x_k - pi(q_k)``, ``q_k = T_i_j Exp(xi) X_k``. With ``P_k = d pi / d q`` and
    ``R`` the rotation of ``T_i_j``: ``J_xi = P_k R [-[X_k]x, I]``, ``J_X = P_k R``. Each residual
    has covariance ``S_k = sigma_k^2 I + J_X Sigma_X J_X^T`` (keypoint noise of the query plus
    the candidate point's stereo uncertainty), so the Gauss-Newton information is
    ``Lambda = sum_k J_xi^T S_k^-1 J_xi``. It is divided by the a-posteriori variance factor
    ``c = max(1, sum_k r_k^T S_k^-1 r_k / (2n - 6))``, so that residuals larger than the
    noise model predicts make the loop weaker, never stronger. Returns ``(Lambda / c, c)``.
    """
    J, PR = reprojection_jacobians(T_i_j, points_j, camera)
    S = pixel_sigmas[:, None, None] ** 2 * np.eye(2)[None] + PR @ point_covariances @ np.transpose(PR, (0, 2, 1))
    S_inv = np.linalg.inv(S)
    info = np.einsum("nai,nab,nbj->ij", J, S_inv, J)
    uv, _ = reprojection(T_i_j, points_j, camera)
    r = uv_i - uv
    chi2 = float(np.einsum("na,nab,nb->", r, S_inv, r))
    c = max(1.0, chi2 / max(2 * points_j.shape[0] - 6, 1))
    info = 0.5 * (info + info.T) / c
    return info, c


def _to_matrix(rvec: NDArray, tvec: NDArray) -> FloatArray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
    T[:3, 3] = np.asarray(tvec, dtype=np.float64).reshape(3)
    return T


def verify_pnp(points_j: FloatArray, point_covariances: FloatArray, uv_i: FloatArray, pixel_sigmas: FloatArray,
               camera: PinholeCamera, params: VerificationConfig = VerificationConfig()) -> PnPResult | None:
    """Relative pose ``T_i_j`` from matched 3-D points of j (M, 3) and pixels of i (M, 2), or None.

    ``cv2.solvePnPRansac`` (threshold ``reprojection_threshold_px``), then ``cv2.solvePnPRefineLM``
    on its inliers, then the inliers are re-counted under the refined pose (in front of the
    camera, error below the threshold) and refined once more. Accepted when the final inlier
    count is at least ``min_inliers`` and ``min_inlier_ratio`` of the M matches. The information
    is :func:`pose_information` of the inliers with the covariance floor added.
    """
    m = points_j.shape[0]
    if m < max(params.min_inliers, 6):
        return None
    obj = np.ascontiguousarray(points_j, dtype=np.float64)
    img = np.ascontiguousarray(uv_i, dtype=np.float64)
    K = camera.K
    cv2.setRNGSeed(int(params.ransac_seed))  # reproducible RANSAC (OpenCV's global RNG)
    ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, K, None, iterationsCount=int(params.ransac_iterations),
                                             reprojectionError=float(params.reprojection_threshold_px),
                                             confidence=float(params.ransac_confidence),
                                             flags=cv2.SOLVEPNP_EPNP)
    if not ok or inl is None or len(inl) < max(params.min_inliers, 6):
        return None
    inliers = np.asarray(inl, dtype=np.int64).reshape(-1)
    for _ in range(2):
        rvec, tvec = cv2.solvePnPRefineLM(obj[inliers], img[inliers], K, None, rvec.copy(), tvec.copy())
        T = _to_matrix(rvec, tvec)
        uv, z = reprojection(T, obj, camera)
        err = np.linalg.norm(uv - img, axis=1)
        inliers = np.flatnonzero((z > 0) & (err < params.reprojection_threshold_px))
        if inliers.size < max(params.min_inliers, 6):
            return None
    if inliers.size < params.min_inliers or inliers.size < params.min_inlier_ratio * m:
        return None
    rmse = float(np.sqrt(np.mean(err[inliers] ** 2)))
    info, _ = pose_information(T, obj[inliers], point_covariances[inliers], img[inliers], pixel_sigmas[inliers],
                               camera)
    floor = np.diag([params.min_rotation_sigma_rad**2] * 3 + [params.min_translation_sigma_m**2] * 3)
    cov = np.linalg.inv(info) + floor
    info = np.linalg.inv(cov)
    return PnPResult(T, inliers, m, rmse, 0.5 * (info + info.T))
