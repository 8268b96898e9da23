"""Exact wheel logs for tests: the planar motion of a base carried by a camera of known poses,
read through a known calibration error (the test-side stand-in of gtvo.datasets.wheel's simulator)."""

from __future__ import annotations

import numpy as np

from factors.odometry_calibration import wheel_arcs
from gtvo.wheel_calibration.diff_drive import diff_drive_motions_from_arcs
from gtvo.wheel_calibration.motions import relative_motions

#: the camera axes (z forward, x right, y down) in a REP 103 base (x forward, y left, z up)
R_BASE_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def planar_base_poses(T_world_cam: np.ndarray, T_base_cam: np.ndarray) -> np.ndarray:
    """(N, 3) planar poses x, y, theta (theta unwrapped) of the base in the first base pose's frame."""
    B = np.asarray(T_world_cam) @ np.linalg.inv(T_base_cam)
    B = np.linalg.inv(B[0]) @ B
    theta = np.unwrap(np.arctan2(B[:, 1, 0], B[:, 0, 0]))
    return np.column_stack([B[:, 0, 3], B[:, 1, 3], theta])


def raw_diff_drive(true_motion: np.ndarray, k: np.ndarray, nominal_baseline: float) -> np.ndarray:
    """The raw motion a diff-drive robot with wheel scales ``k = (k_L, k_R, k_b)`` logs (nominal
    radii and track width ``b0``) for a true arc motion."""
    s_l, s_r = wheel_arcs(np.asarray(true_motion, dtype=float).reshape(1, 3), k[2] * nominal_baseline)
    return diff_drive_motions_from_arcs(s_l / k[0], s_r / k[1], nominal_baseline)[0]


class PlanarWheelLog:
    """A wheel log from planar base poses at ``times``, linearly interpolated; ``raw(v)`` turns a
    true motion into the logged one (default: exact)."""

    def __init__(self, times, poses, raw=None) -> None:
        self.times = np.asarray(times, dtype=float)
        self.poses = np.asarray(poses, dtype=float)
        self.raw = raw or (lambda v: v)

    def covers(self, t0: float, t1: float) -> bool:
        return bool(self.times[0] <= t0 and t1 <= self.times[-1])

    def between(self, t0: float, t1: float) -> np.ndarray:
        p = np.array([[np.interp(t, self.times, self.poses[:, j]) for j in range(3)] for t in (t0, t1)])
        return np.asarray(self.raw(relative_motions(p)[0]), dtype=float)
