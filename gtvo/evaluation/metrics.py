"""Trajectory error metrics: pure numpy math, no file I/O (docs/evaluation.md).

* :func:`umeyama_alignment`: least-squares SE(3) / Sim(3) that maps ``src`` points onto ``dst``.
* :func:`ate`: absolute trajectory error (evo's APE, translation part) after aligning the
  estimate to the reference with ``"se3"``, ``"sim3"``, ``"origin"`` or ``"none"``.
* :func:`rpe`: relative pose error ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` over consecutive pairs
  (evo's RPE), translation in metres and rotation in degrees.
* :func:`drift_percent`: final position error after aligning the first pose, per path length.
* :func:`kitti_segment_errors`: the KITTI odometry devkit's segment metric (% and deg/100 m).

Every function takes two trajectories that are already associated pose by pose (same length,
``est`` pose k belongs to ``ref`` pose k): call :func:`gtvo.evaluation.trajectory.synchronize` first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.errors import InputError
from gtvo.evaluation.trajectory import FloatArray, Trajectory
from gtvo.core.lie import invert_poses, rotation_angle

Alignment = Literal["se3", "sim3", "origin", "none"]
DeltaUnit = Literal["frames", "m"]
PairsFrom = Literal["est", "ref"]

#: Umeyama is degenerate when singular value 2 of the covariance is <= this times singular value 1.
DEGENERATE_SINGULAR_RATIO = 1e-12
#: The KITTI odometry benchmark's segment lengths in metres.
KITTI_SEGMENT_LENGTHS: tuple[float, ...] = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


# ---------------------------------------------------------------------------------------------
# Statistics
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ErrorStatistics:
    """Summary of a 1-D error array, computed as evo does.

    ``rmse = sqrt(mean(e^2))``, ``std`` is the population standard deviation (``np.std``),
    ``sse = sum(e^2)``.
    """

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    count: int

    @classmethod
    def of(cls, errors: ArrayLike) -> "ErrorStatistics":
        """Statistics of ``errors`` (must be non-empty)."""
        e = np.asarray(errors, dtype=np.float64).reshape(-1)
        if e.size == 0:
            raise InputError("no errors to summarise (empty error array)")
        sq = e * e
        return cls(rmse=math.sqrt(float(np.mean(sq))), mean=float(np.mean(e)), median=float(np.median(e)),
                   std=float(np.std(e)), min=float(np.min(e)), max=float(np.max(e)), sse=float(np.sum(sq)),
                   count=int(e.size))

    def as_dict(self) -> dict[str, float]:
        """The statistics as a plain dict (for JSON reports)."""
        return {"rmse": self.rmse, "mean": self.mean, "median": self.median, "std": self.std,
                "min": self.min, "max": self.max, "sse": self.sse, "count": self.count}


# ---------------------------------------------------------------------------------------------
# Umeyama alignment
# ---------------------------------------------------------------------------------------------

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


def _check_pair(est: Trajectory, ref: Trajectory, what: str) -> None:
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
    _check_pair(est, ref, "align_trajectory")
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


# ---------------------------------------------------------------------------------------------
# ATE
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ATEResult:
    """Absolute trajectory error after alignment.

    Attributes:
        translation_errors: (N,) ``|p_est_aligned_i - p_ref_i|`` in metres.
        rotation_errors_deg: (N,) angle of ``R_est_aligned_i^T R_ref_i`` in degrees.
        alignment: the transform applied to the estimate.
        align: the alignment mode used.
        timestamps: (N,) the reference's timestamps (for plots over time).
        translation: statistics of ``translation_errors`` (``.rmse`` is "the ATE").
        rotation_deg: statistics of ``rotation_errors_deg``.
    """

    translation_errors: FloatArray
    rotation_errors_deg: FloatArray
    alignment: SimilarityTransform
    align: str
    timestamps: FloatArray
    translation: ErrorStatistics
    rotation_deg: ErrorStatistics

    @property
    def rmse(self) -> float:
        """Translation RMSE in metres (evo's APE rmse)."""
        return self.translation.rmse


def ate(est: Trajectory, ref: Trajectory, align: Alignment = "se3") -> ATEResult:
    """Absolute trajectory error of associated trajectories (evo ``evo_ape -a`` / ``-as``).

    The estimate is aligned to the reference (:func:`align_trajectory`), then per pose the
    translation error ``|p_est_i' - p_ref_i|`` and the rotation angle of ``R_est_i'^T R_ref_i``.
    """
    _check_pair(est, ref, "ate")
    aligned, S = align_trajectory(est, ref, align)
    t_err = np.linalg.norm(aligned.positions - ref.positions, axis=1)
    E_rot = np.einsum("nji,njk->nik", aligned.rotations, ref.rotations)
    r_err = np.degrees(rotation_angle(E_rot))
    return ATEResult(t_err, r_err, S, align, ref.timestamps.copy(), ErrorStatistics.of(t_err),
                     ErrorStatistics.of(r_err))


# ---------------------------------------------------------------------------------------------
# RPE
# ---------------------------------------------------------------------------------------------

def pairs_by_frames(n: int, delta: int) -> NDArray[np.int64]:
    """Consecutive index pairs ``(0, d), (d, 2d), ...`` with ``j < n`` (evo, ``all_pairs=False``)."""
    if delta < 1:
        raise InputError(f"RPE delta in frames must be >= 1, got {delta}")
    ids = np.arange(0, n, delta, dtype=np.int64)
    return np.column_stack([ids[:-1], ids[1:]]).astype(np.int64)


def pairs_by_path(positions: ArrayLike, delta: float, legacy: bool = False) -> NDArray[np.int64]:
    """Consecutive index pairs each spanning at least ``delta`` metres of travelled path.

    Walking along the poses, the path since the last kept index is summed step by step; the
    first pose at which it reaches ``>= delta`` is kept and the sum restarts at 0. The pairs
    are consecutive kept indices. The first kept index is pose 0 (current evo, checked with
    1.38.1), or with ``legacy=True`` the first pose at which the path from pose 0 reaches
    ``delta`` (older evo releases; the results stored in evo's test data were made that way).
    """
    P = np.asarray(positions, dtype=np.float64)
    delta = float(delta)
    if not np.isfinite(delta) or delta <= 0:
        raise InputError(f"RPE delta in metres must be finite and positive, got {delta!r}")
    n = len(P)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    step = np.linalg.norm(np.diff(P, axis=0), axis=1)  # step[k]: pose k -> k+1
    cum = np.concatenate(([0.0], np.cumsum(step)))
    kept: list[int] = []
    start = 0
    if not legacy:
        kept.append(0)
    # One iteration per kept pose (path / delta of them), not per pose. The global cumulative sum
    # proposes the index; a local running sum, restarted at `start` as evo does, confirms it so
    # rounding can never pick a different pose than the sequential sum.
    while start < n - 1:
        guess = int(np.searchsorted(cum, cum[start] + delta, side="left"))
        hi = min(max(guess + 4, start + 2), n)
        local = np.cumsum(step[start:hi - 1])
        hit = np.flatnonzero(local >= delta)
        if hit.size == 0 and hi < n:
            local = np.cumsum(step[start:])
            hit = np.flatnonzero(local >= delta)
        if hit.size == 0:
            break
        start = start + int(hit[0]) + 1
        kept.append(start)
    ids = np.asarray(kept, dtype=np.int64)
    return np.column_stack([ids[:-1], ids[1:]]).astype(np.int64) if ids.size > 1 else np.zeros((0, 2), np.int64)


def relative_pose_errors(est_poses: ArrayLike, ref_poses: ArrayLike, pairs: ArrayLike) -> FloatArray:
    """(K, 4, 4) ``E_k = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` for pairs ``(i, j)``; ``Q`` ref, ``P`` est."""
    P = np.asarray(est_poses, dtype=np.float64)
    Q = np.asarray(ref_poses, dtype=np.float64)
    ij = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    Q_rel = invert_poses(Q[ij[:, 0]]) @ Q[ij[:, 1]]
    P_rel = invert_poses(P[ij[:, 0]]) @ P[ij[:, 1]]
    return invert_poses(Q_rel) @ P_rel


@dataclass(frozen=True)
class RPEResult:
    """Relative pose errors over consecutive pairs.

    Attributes:
        pairs: (K, 2) index pairs ``(i, j)``.
        translation_errors: (K,) ``|trans(E_k)|`` in metres.
        rotation_errors_deg: (K,) rotation angle of ``E_k`` in degrees.
        timestamps: (K,) the reference's timestamp at ``j`` (for plots over time).
        translation, rotation_deg: their statistics.
        delta, delta_unit: the pair spacing used.
    """

    pairs: NDArray[np.int64]
    translation_errors: FloatArray
    rotation_errors_deg: FloatArray
    timestamps: FloatArray
    translation: ErrorStatistics
    rotation_deg: ErrorStatistics
    delta: float
    delta_unit: str


def rpe(est: Trajectory, ref: Trajectory, delta: float = 1, delta_unit: DeltaUnit = "frames",
        pairs_from: PairsFrom = "est", legacy_path_pairs: bool = False) -> RPEResult:
    """Relative pose error of associated trajectories, as evo's ``RPE`` with consecutive pairs.

    For each pair ``(i, j)``: ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` with ``Q`` the reference and
    ``P`` the estimate; the translation error is ``|trans(E)|`` and the rotation error the angle
    of ``rot(E)``. No alignment is needed: relative motions do not depend on the world frame
    (but a Sim(3)-scaled estimate must be scaled first).

    Args:
        delta: pair spacing, in frames (an integer) or metres of travelled path.
        delta_unit: ``"frames"`` (pairs ``(0, d), (d, 2d), ...``) or ``"m"`` (:func:`pairs_by_path`).
        pairs_from: whose path picks the pairs for ``"m"``: ``"est"`` (evo's default) or ``"ref"``
            (evo's ``pairs_from_reference``).
        legacy_path_pairs: reproduce older evo releases' path pairing (see :func:`pairs_by_path`).

    Raises:
        InputError: lengths differ, bad delta, or no pair fits.
    """
    _check_pair(est, ref, "rpe")
    if delta_unit == "frames":
        if float(delta) != int(delta):
            raise InputError(f"RPE delta in frames must be an integer, got {delta!r}")
        pairs = pairs_by_frames(len(est), int(delta))
    elif delta_unit == "m":
        if pairs_from not in ("est", "ref"):
            raise InputError(f"pairs_from must be 'est' or 'ref', got {pairs_from!r}")
        source = est if pairs_from == "est" else ref
        pairs = pairs_by_path(source.positions, float(delta), legacy=legacy_path_pairs)
    else:
        raise InputError(f"unknown RPE delta unit {delta_unit!r}: use 'frames' or 'm'")
    if len(pairs) == 0:
        raise InputError(f"RPE: delta = {delta} {delta_unit} gives no pose pair in {len(est)} poses; "
                         "use a smaller delta")
    E = relative_pose_errors(est.poses, ref.poses, pairs)
    t_err = np.linalg.norm(E[:, :3, 3], axis=1)
    r_err = np.degrees(rotation_angle(E[:, :3, :3]))
    return RPEResult(pairs, t_err, r_err, ref.timestamps[pairs[:, 1]].copy(), ErrorStatistics.of(t_err),
                     ErrorStatistics.of(r_err), float(delta), delta_unit)


# ---------------------------------------------------------------------------------------------
# Drift and the KITTI segment metric
# ---------------------------------------------------------------------------------------------

def drift_percent(est: Trajectory, ref: Trajectory) -> float:
    """Final position error after aligning the first pose, in percent of the reference path length.

    ``est' = T_ref[0] T_est[0]^-1 est`` (the ``"origin"`` alignment: first poses coincide), then
    ``100 * |p_est'[-1] - p_ref[-1]| / L`` with ``L`` the reference's path length.

    Raises:
        InputError: lengths differ or the reference does not move (``L = 0``).
    """
    _check_pair(est, ref, "drift_percent")
    length = ref.path_length()
    if not length > 0:
        raise InputError("drift_percent: the reference path length is 0 (it does not move)")
    aligned, _ = align_trajectory(est, ref, "origin")
    return float(100.0 * np.linalg.norm(aligned.positions[-1] - ref.positions[-1]) / length)


@dataclass(frozen=True)
class KittiSegmentResult:
    """The KITTI devkit's segment errors.

    Attributes:
        translation_percent: mean over all segments of ``t_err / len``, times 100.
        rotation_deg_per_100m: mean over all segments of ``r_err / len`` (rad/m), in deg per 100 m.
        first_frames, segment_lengths: (K,) the segments' first frame and nominal length (m).
        last_frames: (K,) their last frame.
        translation_ratios: (K,) ``t_err / len`` (unitless).
        rotation_rad_per_m: (K,) ``r_err / len``.
        per_length: ``{length: (translation_percent, rotation_deg_per_100m, count)}`` for each
            length with at least one segment.
    """

    translation_percent: float
    rotation_deg_per_100m: float
    first_frames: NDArray[np.int64]
    last_frames: NDArray[np.int64]
    segment_lengths: FloatArray
    translation_ratios: FloatArray
    rotation_rad_per_m: FloatArray
    per_length: dict[float, tuple[float, float, int]]


def kitti_segment_errors(est: Trajectory, ref: Trajectory, lengths: Sequence[float] = KITTI_SEGMENT_LENGTHS,
                         step: int = 10) -> KittiSegmentResult | None:
    """The KITTI odometry devkit's metric (``evaluate_odometry.cpp``, ``calcSequenceErrors``).

    ``dist`` is the reference's accumulated path length (:meth:`Trajectory.distances`). For
    every ``step``-th first frame ``f`` and every length ``L``, the last frame is the first
    ``l >= f`` with ``dist[l] > dist[f] + L``; segments without one are skipped. Then
    ``E = (P_f^-1 P_l)^-1 (Q_f^-1 Q_l)`` (``P`` estimate, ``Q`` reference), ``t_err = |trans(E)|``,
    ``r_err = acos(clip((trace(rot E) - 1) / 2, -1, 1))``, each divided by ``L``; the results are
    the means over all segments (``t`` times 100 in %, ``r`` in degrees per 100 m). The devkit
    computes in single precision; this uses double.

    For short trajectories pass smaller ``lengths`` (e.g. ``(5, 10, 20)``): the benchmark's
    100..800 m need a path longer than 100 m.

    Returns:
        The result, or ``None`` when no segment of any length fits in the trajectory.

    Raises:
        InputError: lengths differ, a length is not positive, or ``step < 1``.
    """
    _check_pair(est, ref, "kitti_segment_errors")
    L = np.asarray(lengths, dtype=np.float64).reshape(-1)
    if L.size == 0 or not np.all(np.isfinite(L)) or np.any(L <= 0):
        raise InputError(f"kitti_segment_errors: lengths must be positive numbers, got {list(lengths)}")
    if int(step) < 1:
        raise InputError(f"kitti_segment_errors: step must be >= 1, got {step}")
    dist = ref.distances()
    first = np.arange(0, len(ref), int(step), dtype=np.int64)
    F, LL = np.meshgrid(first, L, indexing="ij")  # (n_first, n_lengths)
    last = np.searchsorted(dist, dist[F] + LL, side="right")  # first index with dist > dist[f] + L
    ok = last < len(ref)
    if not np.any(ok):
        return None
    f, l, seg = F[ok], last[ok].astype(np.int64), LL[ok]
    delta_ref = invert_poses(ref.poses[f]) @ ref.poses[l]
    delta_est = invert_poses(est.poses[f]) @ est.poses[l]
    E = invert_poses(delta_est) @ delta_ref
    t_err = np.linalg.norm(E[:, :3, 3], axis=1) / seg
    c = 0.5 * (E[:, 0, 0] + E[:, 1, 1] + E[:, 2, 2] - 1.0)
    r_err = np.arccos(np.clip(c, -1.0, 1.0)) / seg
    per_length: dict[float, tuple[float, float, int]] = {}
    for length in L:  # one entry per requested length, not per segment
        m = seg == length
        if np.any(m):
            per_length[float(length)] = (float(100.0 * np.mean(t_err[m])),
                                         float(np.degrees(np.mean(r_err[m])) * 100.0), int(np.sum(m)))
    return KittiSegmentResult(float(100.0 * np.mean(t_err)), float(np.degrees(np.mean(r_err)) * 100.0),
                              f, l, seg, t_err, r_err, per_length)
