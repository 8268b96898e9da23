"""The optical-flow + PnP pose guess (gtvo/frontend/flow_pose.py).

Bounds from what was measured (docs/frontend.md): on the synthetic room, 0.3-1.2 m steps come out
within 4 cm / 0.2 deg with exact depths; on KITTI_sequence_1 with gtvo's own stereo depths, 2.4 m
steps within 8 cm / 0.26 deg (frames 0-40 every 5). The asserted bounds leave 2-3x margin and
stay far below the error of the guess the tracker would otherwise start from (the full step).
"""

from __future__ import annotations

import numpy as np
import pytest

from gtvo.errors import InputError
from gtvo.frontend import init_keyframe_points, select_points
from gtvo.frontend import FlowPoseConfig, optical_flow_pose
from gtvo.datasets.synthetic import make_synthetic_sequence


def _errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    E = np.linalg.inv(T_true) @ T_est
    angle = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    return float(np.linalg.norm(E[:3, 3])), float(angle)


@pytest.fixture(scope="module")
def room():
    seq = make_synthetic_sequence(n_frames=9)
    left = seq.left(0)
    px = select_points(left, target=300)
    z = seq.true_depth(0)[np.rint(px[:, 1]).astype(int), np.rint(px[:, 0]).astype(int)]
    return seq, left, px, 1.0 / z


@pytest.mark.slow
@pytest.mark.parametrize("step", [2, 4, 8])
def test_synthetic_steps_come_out_close_to_the_truth(room, step):
    seq, left, px, d = room
    guess = optical_flow_pose(seq.camera.left, left, px, d, seq.left(step))
    assert guess is not None
    T_true = np.linalg.inv(seq.gt_poses[0]) @ seq.gt_poses[step]
    t_err, r_err = _errors(guess.T_keyframe_frame, T_true)
    assert t_err < 0.05 and r_err < 0.3
    assert t_err < 0.2 * np.linalg.norm(T_true[:3, 3])
    assert guess.n_inliers >= FlowPoseConfig().min_inliers and guess.n_inliers <= guess.n_tracked


def test_unrelated_images_give_no_guess(room):
    seq, left, px, d = room
    rng = np.random.default_rng(0)
    noise = rng.uniform(0, 255, size=left.shape).astype(np.float32)
    assert optical_flow_pose(seq.camera.left, left, px, d, noise) is None


def test_bad_input_is_rejected(room):
    seq, left, px, d = room
    with pytest.raises(InputError, match="inverse depths"):
        optical_flow_pose(seq.camera.left, left, px, d[:-1], left)
    with pytest.raises(InputError, match="frame image is 100x50"):
        optical_flow_pose(seq.camera.left, left, px, d, np.zeros((50, 100), np.float32))
    with pytest.raises(InputError, match="odd"):
        FlowPoseConfig(window_px=20)
    # too few usable points (NaN / non-positive inverse depths): no guess, no exception
    bad = np.full_like(d, np.nan)
    assert optical_flow_pose(seq.camera.left, left, px, bad, seq.left(1)) is None


@pytest.mark.realdata
def test_kitti_two_frames_apart(kitti_snippet):
    seq = kitti_snippet()
    for a in (10, 20):
        left = seq.left(a)
        pts = init_keyframe_points(left, seq.right(a), seq.camera, target=300)
        guess = optical_flow_pose(seq.camera.left, left, pts.pixels, pts.inverse_depth, seq.left(a + 2))
        assert guess is not None
        T_true = np.linalg.inv(seq.gt_poses[a]) @ seq.gt_poses[a + 2]
        t_err, r_err = _errors(guess.T_keyframe_frame, T_true)
        assert np.linalg.norm(T_true[:3, 3]) > 2.0  # a step the motion model cannot guess from rest
        assert t_err < 0.2 and r_err < 0.5
