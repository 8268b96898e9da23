"""What observers read (gtvo/odometry/view.py): data made by the odometry, not the system."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from gtvo.config import OdometryConfig
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.odometry import OdometryView, VisualOdometry
from gtvo.pipeline import process_sequence


def test_the_view_carries_the_trackers_residuals_at_the_tracked_pose():
    seq = make_synthetic_sequence(n_frames=3)
    vo = VisualOdometry(seq.camera, OdometryConfig(mode="track"))
    vo.process(seq.frame(0))
    assert vo.view().tracked is None  # the first frame is not tracked
    est = vo.process(seq.frame(1))
    view = vo.view()
    tracked = view.tracked
    assert tracked is not None and tracked.keyframe_index == 0
    assert tracked.pixels.shape[0] == tracked.X_world.shape[0] == tracked.residual.shape[0] > 100
    assert np.median(tracked.residual) < 3.0
    # the world points project at the tracked pose onto the pixels the tracker compared
    T_cam_world = np.linalg.inv(est.T_world_cam)
    uv, _ = seq.pinhole.project(tracked.X_world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3])
    assert np.median(np.linalg.norm(uv - tracked.pixels, axis=1)) < 0.05
    # the residuals are computed for a view only: the recorded estimate carries none (memory)
    assert est.tracking is not None and not hasattr(est.tracking, "residuals")


def test_residuals_grow_off_the_tracked_pose():
    """The residuals are the tracker's own at a pose: 2 deg off the solution they are much larger."""
    from gtvo.frontend.tracking import frame_pyramid, point_residuals

    seq = make_synthetic_sequence(n_frames=2)
    vo = VisualOdometry(seq.camera, OdometryConfig(mode="track"))
    vo.process(seq.frame(0))
    vo.process(seq.frame(1))
    tracker = vo.keyframes[0].tracker
    result = vo.estimates[1].tracking
    target = frame_pyramid(np.asarray(seq.frame(1).left, dtype=np.float32), tracker.levels)[0]
    good = point_residuals(tracker, target, result.T_keyframe_frame, result.affine)
    off = point_residuals(tracker, target, result.T_keyframe_frame.compose(
        gtsam.Pose3(gtsam.Rot3.Yaw(np.radians(2.0)), gtsam.Point3(0, 0, 0))), result.affine)
    assert good.residual.size > 100 and off.residual.size > 0
    assert np.median(good.residual) < 3.0
    assert np.median(off.residual) > 3 * np.median(good.residual)


@pytest.mark.slow
def test_observers_get_a_view_not_the_odometry():
    seq = make_synthetic_sequence(n_frames=16, step_m=0.15)
    seen: list = []

    class Keep:
        def on_start(self, s, config): seen.append(config)
        def on_frame(self, frame, est, view): seen.append(view)
        def on_finish(self, view, traj, info): seen.append(view)

    process_sequence(seq, OdometryConfig(), observers=[Keep()])
    assert isinstance(seen[0], OdometryConfig)
    views = seen[1:]
    assert len(views) == 17 and all(isinstance(v, OdometryView) for v in views)
    assert not any(hasattr(v, "process") or hasattr(v, "keyframer") for v in views)
    last = views[-1]
    assert last.frame_count == 16 and len(last.window_indices) == len(last.window_poses) >= 2
    X, intensity = last.keyframe_points(last.window_indices[-1])
    assert X.shape == (len(intensity), 3)
    X[:] = 0.0  # a copy: changing it changes nothing
    X2, _ = last.keyframe_points(last.window_indices[-1])
    assert np.any(X2 != 0.0)
    assert last.positions().shape == (16, 3)
    assert last.right_brightness is not None and abs(last.right_brightness[0]) < 0.1


@pytest.mark.parametrize("solver", ["handrolled", "gtsam"])
def test_a_run_without_a_robust_kernel_tracks_and_has_a_view(solver):
    """``photometric.huber_k: null`` (no robust kernel, allowed by the config) tracks with both
    solvers: the lost-pixel cost is the square's, and the view's colour scale the default kernel's."""
    from factors.gtsam_factors import DEFAULT_HUBER_K, DEFAULT_SIGMA_INTENSITY
    from factors.params import PhotometricConfig

    seq = make_synthetic_sequence(n_frames=4)
    vo, _, info = process_sequence(seq, OdometryConfig(photometric=PhotometricConfig(huber_k=None), solver=solver),
                                   warn=lambda m: None)
    assert info["tracking_failures"] == 0
    assert vo.view().residual_scale == DEFAULT_HUBER_K * DEFAULT_SIGMA_INTENSITY
