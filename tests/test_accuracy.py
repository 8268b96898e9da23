"""gtvo.evaluation.accuracy: the run report's metrics on short and static logs."""

import numpy as np

from gtvo.evaluation.accuracy import MIN_DRIFT_PATH_M, evaluate
from gtvo.evaluation.trajectory import Trajectory


def _line(n, step, wobble=0.0):
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 2, 3] = step * np.arange(n)
    T[:, 0, 3] = wobble * np.sin(np.arange(n))  # off the line: the SE(3) alignment is determined
    return Trajectory(np.arange(n) * 0.1, T)


def test_static_clip_has_no_drift_or_segment_metric():
    """3 mm of ground-truth path: drift % and segment errors would divide noise by noise."""
    ref = _line(10, 0.0003, wobble=0.001)
    est = _line(10, 0.0004, wobble=0.001)
    assert ref.path_length() < MIN_DRIFT_PATH_M
    m = evaluate(est, ref)
    assert m["drift_percent"] is None and "kitti_translation_percent" not in m
    assert m["ate_rmse_m"] is not None and m["ate_rmse_m"] < 1e-3


def test_moving_log_has_drift_and_segments_and_two_poses_no_ate():
    m = evaluate(_line(30, 0.2, wobble=0.05), _line(30, 0.21, wobble=0.05))
    assert m["drift_percent"] > 0 and m["kitti_translation_percent"] is not None
    m2 = evaluate(_line(2, 0.2), _line(2, 0.21))
    assert m2["ate_rmse_m"] is None and "at least 3" in m2["ate_skipped"] and m2["drift_percent"] > 0
