"""Trajectory error metrics: pure numpy math, no file I/O (docs/evaluation.md).

* :func:`umeyama_alignment`: least-squares SE(3) / Sim(3) that maps ``src`` points onto ``dst``.
* :func:`ate`: absolute trajectory error (evo's APE, translation part) after aligning the
  estimate to the reference with ``"se3"``, ``"sim3"``, ``"origin"`` or ``"none"``.
* :func:`rpe`: relative pose error ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` over consecutive pairs
  (evo's RPE), translation in metres and rotation in degrees.
* :func:`drift_percent` and :func:`kitti_segment_errors` (the KITTI devkit's segment metric) live in
  :mod:`gtvo.evaluation.drift` and are imported here too.

Every function takes two trajectories that are already associated pose by pose (same length,
``est`` pose k belongs to ``ref`` pose k): call :func:`gtvo.evaluation.trajectory.synchronize` first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.errors import InputError, show
from gtvo.evaluation.trajectory import FloatArray, Trajectory
from gtvo.core.lie import invert_poses, rotation_angle
from gtvo.evaluation.alignment import (Alignment, SimilarityTransform, align_trajectory, check_pair,
                                       umeyama_alignment)
from gtvo.evaluation.drift import KITTI_SEGMENT_LENGTHS, KittiSegmentResult, drift_percent, kitti_segment_errors

DeltaUnit = Literal["frames", "m"]
PairsFrom = Literal["est", "ref"]

__all__ = ["ATEResult", "Alignment", "DeltaUnit", "ErrorStatistics", "KITTI_SEGMENT_LENGTHS", "KittiSegmentResult",
           "RPEResult", "SimilarityTransform", "align_trajectory", "ate", "drift_percent", "kitti_segment_errors",
           "pairs_by_frames", "pairs_by_path", "relative_pose_errors", "rpe", "umeyama_alignment"]



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
    check_pair(est, ref, "ate")
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
        raise InputError(f"RPE delta in metres must be finite and positive, got {show(delta)}")
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
    check_pair(est, ref, "rpe")
    if delta_unit == "frames":
        if float(delta) != int(delta):
            raise InputError(f"RPE delta in frames must be an integer, got {show(delta)}")
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
