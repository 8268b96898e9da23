"""Drift: the end-point drift and the KITTI odometry devkit's segment metric (docs/evaluation.md).

* :func:`drift_percent`: final position error after aligning the first pose, per path length
  (an end-point figure: on a short snippet it hinges on the ground truth at frame 0).
* :func:`kitti_segment_errors`: the devkit's segment errors from every start frame, in % and
  deg/100 m, over the lengths :data:`KITTI_SEGMENT_LENGTHS` (or shorter ones for short logs).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from gtvo.core.lie import invert_poses
from gtvo.errors import InputError
from gtvo.evaluation.alignment import align_trajectory, check_pair
from gtvo.evaluation.trajectory import FloatArray, Trajectory

#: The KITTI odometry benchmark's segment lengths in metres.
KITTI_SEGMENT_LENGTHS: tuple[float, ...] = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


def drift_percent(est: Trajectory, ref: Trajectory) -> float:
    """Final position error after aligning the first pose, in percent of the reference path length.

    ``est' = T_ref[0] T_est[0]^-1 est`` (the ``"origin"`` alignment: first poses coincide), then
    ``100 * |p_est'[-1] - p_ref[-1]| / L`` with ``L`` the reference's path length.

    Raises:
        InputError: lengths differ or the reference does not move (``L = 0``).
    """
    check_pair(est, ref, "drift_percent")
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
    check_pair(est, ref, "kitti_segment_errors")
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
