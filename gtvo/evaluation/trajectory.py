"""Timestamped trajectories of ``T_world_cam`` poses: pure math, no file I/O.

A :class:`Trajectory` holds ``timestamps`` (N,) in seconds and ``poses`` (N, 4, 4), each the
pose ``T_world_cam`` of the left camera (docs/conventions.md). Readers and writers live in
:mod:`gtvo.io.trajectory_files`, metrics in :mod:`gtvo.evaluation.metrics`, plots in :mod:`gtvo.io.plots`.

Timestamps must be finite and **non-decreasing** (duplicates are allowed: real ground-truth
files contain a few). Rotation blocks are kept exactly as given (a KITTI file's rotations are
only orthonormal to its printed precision); the inverse of a pose is taken as
``[R^T, -R^T t]`` everywhere, as evo and the KITTI devkit do.

Association (:func:`associate`) pairs the poses of two trajectories by nearest timestamp
within ``max_diff`` seconds (default 0.01 s), exactly as evo's ``sync.associate_trajectories``
with its ``nearest_time`` method; docs/evaluation.md gives the rule.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.core.lie import invert_poses, rotations_to_quaternions
from gtvo.errors import InputError, show

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Default association tolerance in seconds (evo's default ``max_diff``).
DEFAULT_MAX_TIME_DIFF = 0.01


# ---------------------------------------------------------------------------------------------
# Trajectory
# ---------------------------------------------------------------------------------------------

@dataclass
class Trajectory:
    """Timestamped poses ``T_world_cam``.

    Attributes:
        timestamps: (N,) seconds, finite and non-decreasing.
        poses: (N, 4, 4) homogeneous ``T_world_cam`` (last row ``[0, 0, 0, 1]``).
        name: a label for messages and plot legends (e.g. the file it came from).
    """

    timestamps: FloatArray
    poses: FloatArray
    name: str = field(default="")

    def __post_init__(self) -> None:
        where = self.name or "trajectory"
        self.timestamps = np.asarray(self.timestamps, dtype=np.float64).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=np.float64)
        n = self.timestamps.size
        if n == 0:
            raise InputError(f"{where}: empty trajectory (no poses)")
        if self.poses.shape != (n, 4, 4):
            raise InputError(f"{where}: poses have shape {self.poses.shape}, expected ({n}, 4, 4)")
        if not np.all(np.isfinite(self.timestamps)):
            raise InputError(f"{where}: timestamps contain NaN or infinite values")
        if not np.all(np.isfinite(self.poses)):
            k = int(np.argmax(~np.all(np.isfinite(self.poses), axis=(1, 2))))
            raise InputError(f"{where}: pose {k} contains NaN or infinite values")
        back = np.diff(self.timestamps) < 0
        if np.any(back):
            k = int(np.argmax(back)) + 1
            raise InputError(f"{where}: timestamps go backwards at pose {k} "
                             f"({float(self.timestamps[k - 1])!r} -> {float(self.timestamps[k])!r})")
        if not np.allclose(self.poses[:, 3, :], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=1e-12):
            raise InputError(f"{where}: the last row of every pose must be [0, 0, 0, 1]")

    def __len__(self) -> int:
        return int(self.timestamps.size)

    @property
    def positions(self) -> FloatArray:
        """(N, 3) camera centres in the world frame (the translation of ``T_world_cam``)."""
        return self.poses[:, :3, 3]

    @property
    def rotations(self) -> FloatArray:
        """(N, 3, 3) rotations ``R_world_cam``."""
        return self.poses[:, :3, :3]

    def quaternions_xyzw(self) -> FloatArray:
        """(N, 4) unit quaternions ``qx qy qz qw`` (``qw >= 0``) of the rotations."""
        return rotations_to_quaternions(self.rotations)

    def distances(self) -> FloatArray:
        """(N,) accumulated path length from the first pose: ``d[0] = 0``, ``d[i] = d[i-1] + |p_i - p_{i-1}|``."""
        step = np.linalg.norm(np.diff(self.positions, axis=0), axis=1)
        return np.concatenate(([0.0], np.cumsum(step)))

    def path_length(self) -> float:
        """Total path length in metres (sum of the distances between consecutive positions)."""
        return float(np.sum(np.linalg.norm(np.diff(self.positions, axis=0), axis=1)))

    def duration(self) -> float:
        """Last minus first timestamp, in seconds."""
        return float(self.timestamps[-1] - self.timestamps[0])

    def subset(self, indices: ArrayLike) -> "Trajectory":
        """The poses at ``indices`` (in the given order, which must keep time non-decreasing)."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        return Trajectory(self.timestamps[idx].copy(), self.poses[idx].copy(), self.name)

    def relative_to_first(self) -> "Trajectory":
        """The same motion expressed in the first camera's frame: ``T_0^-1 T_i`` (first pose = I)."""
        return self.transform(invert_poses(self.poses[0]))

    def transform(self, T: ArrayLike, scale: float = 1.0) -> "Trajectory":
        """Apply a similarity from the left: ``p_i' = scale * R p_i + t``, ``R_i' = R R_i``.

        ``T`` is a 4x4 rigid transform ``[R, t]`` (the new world from the old one); ``scale``
        (default 1) makes it a Sim(3) action that scales positions, never rotations. This is
        evo's ``scale(s)`` followed by ``transform(T)``.
        """
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"transform must be a finite 4x4 matrix, got shape {T.shape}")
        scale = float(scale)
        if not np.isfinite(scale) or scale <= 0:
            raise InputError(f"transform scale must be finite and positive, got {show(scale)}")
        R, t = T[:3, :3], T[:3, 3]
        poses = np.empty_like(self.poses)
        poses[:, :3, :3] = np.einsum("ij,njk->nik", R, self.rotations)
        poses[:, :3, 3] = scale * self.positions @ R.T + t
        poses[:, 3, :] = (0.0, 0.0, 0.0, 1.0)
        return Trajectory(self.timestamps.copy(), poses, self.name)


# ---------------------------------------------------------------------------------------------
# Association by timestamp
# ---------------------------------------------------------------------------------------------

def matching_time_indices(stamps_1: ArrayLike, stamps_2: ArrayLike, max_diff: float = DEFAULT_MAX_TIME_DIFF,
                          offset_2: float = 0.0) -> tuple[IntArray, IntArray]:
    """For each stamp of ``stamps_1`` the index of the nearest stamp of ``stamps_2 + offset_2``.

    Pairs farther apart than ``max_diff`` are dropped. ``stamps_2`` must be non-decreasing.
    On a tie the earlier stamp of ``stamps_2`` wins; among duplicates of ``stamps_2`` the last
    one is taken. Several stamps of ``stamps_1`` may match the same stamp of ``stamps_2``.
    This is evo's ``sync.matching_time_indices`` (sorted case), vectorised.

    Returns:
        ``(idx_1, idx_2)``: int arrays of equal length, ``idx_1`` increasing.
    """
    s1 = np.asarray(stamps_1, dtype=np.float64).reshape(-1)
    s2 = np.asarray(stamps_2, dtype=np.float64).reshape(-1) + float(offset_2)
    max_diff = float(max_diff)
    if not np.isfinite(max_diff) or max_diff < 0:
        raise InputError(f"max_diff must be a finite non-negative number of seconds, got {show(max_diff)}")
    if s2.size == 0 or s1.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if np.any(np.diff(s2) < 0):
        raise InputError("timestamps to match against must be non-decreasing")
    idx_1 = np.arange(s1.size, dtype=np.int64)
    inside = (s1 >= s2[0] - max_diff) & (s1 <= s2[-1] + max_diff)
    upper = np.minimum(np.searchsorted(s2, s1, side="right"), s2.size - 1)
    diff_ub = s2[upper] - s1
    diff_lb = np.where(upper > 0, s1 - s2[np.maximum(upper - 1, 0)], np.inf)
    take_ub = (diff_ub <= max_diff) & (diff_ub < diff_lb)
    take_lb = ~take_ub & (diff_lb <= max_diff) & (diff_lb <= diff_ub)
    keep = inside & (take_ub | take_lb)
    best = np.where(take_ub, upper, upper - 1)
    return idx_1[keep], best[keep].astype(np.int64)


def associate(ref: Trajectory, est: Trajectory, max_diff: float = DEFAULT_MAX_TIME_DIFF,
              offset: float = 0.0) -> tuple[IntArray, IntArray]:
    """Index pairs ``(ref_idx, est_idx)`` of poses with matching timestamps.

    ``offset`` (seconds) is added to the estimate's timestamps before matching. Matching
    starts from the trajectory with fewer poses (the estimate when both are equally long), so
    none of its poses is lost to a neighbour: each of its stamps takes the nearest stamp of the
    other one within ``max_diff`` (:func:`matching_time_indices`). Same pairs as evo's
    ``sync.associate_trajectories(ref, est, max_diff=max_diff, offset_2=offset)``.

    Raises:
        InputError: when no pair is found.
    """
    if len(est) > len(ref):
        i_ref, i_est = matching_time_indices(ref.timestamps, est.timestamps, max_diff, offset)
    else:
        i_est, i_ref = matching_time_indices(est.timestamps, ref.timestamps, max_diff, -offset)
    if i_ref.size == 0:
        raise InputError(f"no matching timestamps between {ref.name or 'reference'} and "
                         f"{est.name or 'estimate'} within max_diff={max_diff} s (offset {offset} s)")
    return i_ref, i_est


def synchronize(ref: Trajectory, est: Trajectory, max_diff: float = DEFAULT_MAX_TIME_DIFF,
                offset: float = 0.0) -> tuple[Trajectory, Trajectory]:
    """The associated sub-trajectories ``(ref_sub, est_sub)``, pose ``k`` of each paired."""
    i_ref, i_est = associate(ref, est, max_diff, offset)
    return ref.subset(i_ref), est.subset(i_est)
