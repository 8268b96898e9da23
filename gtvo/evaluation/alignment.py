"""Aligning an estimated trajectory to a reference: Umeyama's SE(3) / Sim(3) fit (docs/evaluation.md)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from gtvo.core.lie import invert_poses
from gtvo.errors import InputError
from gtvo.evaluation.trajectory import FloatArray, Trajectory

Alignment = Literal["se3", "sim3", "origin", "none"]

#: Umeyama is degenerate when singular value 2 of the covariance is <= this times singular value 1.
DEGENERATE_SINGULAR_RATIO = 1e-12


@dataclass(frozen=True)
class SimilarityTransform:
    """``x -> scale * rotation @ x + translation`` (scale 1 for a rigid transform)."""

    rotation: FloatArray
    translation: FloatArray
    scale: float = 1.0

    def matrix(self) -> FloatArray:
        """The 4x4 matrix ``[[scale R, t], [0, 1]]``."""
        M = np.eye(4)
        M[:3, :3] = self.scale * self.rotation
        M[:3, 3] = self.translation
        return M

    def rigid_matrix(self) -> FloatArray:
        """The 4x4 rigid part ``[[R, t], [0, 1]]`` (what :meth:`Trajectory.transform` takes)."""
        M = np.eye(4)
        M[:3, :3] = self.rotation
        M[:3, 3] = self.translation
        return M

    def apply(self, points: ArrayLike) -> FloatArray:
        """Transform (N, 3) points."""
        return self.scale * np.asarray(points, dtype=np.float64) @ self.rotation.T + self.translation

    def apply_to(self, traj: Trajectory) -> Trajectory:
        """Transform a trajectory: positions by the similarity, rotations by ``R`` only."""
        return traj.transform(self.rigid_matrix(), self.scale)


def umeyama_alignment(src: ArrayLike, dst: ArrayLike, with_scale: bool = False) -> SimilarityTransform:
    """Least-squares ``(R, t, s)`` minimising ``sum_i |dst_i - (s R src_i + t)|^2`` (Umeyama 1991).

    Args:
        src, dst: (N, 3) corresponding points (N >= 3).
        with_scale: estimate the scale ``s`` (Sim(3)); otherwise ``s = 1`` (SE(3)).

    With means ``mu_s, mu_d``, variance ``sigma_s^2 = mean |src_i - mu_s|^2`` and covariance
    ``C = mean (dst_i - mu_d)(src_i - mu_s)^T = U D V^T``: ``S = diag(1, 1, det(U) det(V))``,
    ``R = U S V^T``, ``s = trace(D S) / sigma_s^2``, ``t = mu_d - s R mu_s``.

    Raises:
        InputError: shapes differ, fewer than 3 points, non-finite values, or degenerate
            geometry: the second singular value of ``C`` is not above
            :data:`DEGENERATE_SINGULAR_RATIO` times the first (all points on one line or in one
            point: the rotation about that line is not determined; evo rejects these too, with
            an absolute threshold).
    """
    X = np.asarray(src, dtype=np.float64)
    Y = np.asarray(dst, dtype=np.float64)
    if X.shape != Y.shape or X.ndim != 2 or X.shape[1] != 3:
        raise InputError(f"umeyama_alignment needs two (N, 3) arrays of the same shape, got {X.shape} and {Y.shape}")
    n = X.shape[0]
    if n < 3:
        raise InputError(f"umeyama_alignment needs at least 3 point pairs, got {n}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
        raise InputError("umeyama_alignment: points contain NaN or infinite values")
    mu_x, mu_y = X.mean(axis=0), Y.mean(axis=0)
    Xc, Yc = X - mu_x, Y - mu_y
    sigma_x = float(np.sum(Xc * Xc)) / n
    cov = Yc.T @ Xc / n
    U, d, Vt = np.linalg.svd(cov)
    if not d[1] > DEGENERATE_SINGULAR_RATIO * d[0]:
        raise InputError("umeyama_alignment: degenerate point sets (covariance rank < 2, e.g. collinear "
                         "or a single point); the alignment is not unique")
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0.0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.sum(d * np.diag(S)) / sigma_x) if with_scale else 1.0
    t = mu_y - s * R @ mu_x
    return SimilarityTransform(R, t, s)


def check_pair(est: Trajectory, ref: Trajectory, what: str) -> None:
    """InputError unless ``est`` and ``ref`` are associated pose by pose (same length, enough poses)."""
    if len(est) != len(ref):
        raise InputError(f"{what}: estimate has {len(est)} poses but reference has {len(ref)}; "
                         "associate them first (gtvo.evaluation.trajectory.synchronize)")


def align_trajectory(est: Trajectory, ref: Trajectory,
                     align: Alignment = "se3") -> tuple[Trajectory, SimilarityTransform]:
    """The estimate mapped into the reference's world, and the transform used.

    ``"se3"``/``"sim3"``: Umeyama on the positions (all pose pairs). ``"origin"``: the rigid
    transform ``T_ref[0] T_est[0]^-1`` that puts the first estimated pose onto the first
    reference pose. ``"none"``: identity.
    """
    check_pair(est, ref, "align_trajectory")
    if align in ("se3", "sim3"):
        S = umeyama_alignment(est.positions, ref.positions, with_scale=(align == "sim3"))
    elif align == "origin":
        M = ref.poses[0] @ invert_poses(est.poses[0])
        S = SimilarityTransform(M[:3, :3].copy(), M[:3, 3].copy(), 1.0)
    elif align == "none":
        S = SimilarityTransform(np.eye(3), np.zeros(3), 1.0)
    else:
        raise InputError(f"unknown alignment {align!r}: use 'se3', 'sim3', 'origin' or 'none'")
    return S.apply_to(est), S


