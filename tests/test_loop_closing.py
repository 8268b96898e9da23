"""Loop closing of a VO run: place recognition over keyframes + robust keyframe pose graph."""

import numpy as np

from gtvo.loops.closing import close_loops_of_run, relocate_frames
from gtvo.config import FrontendConfig, KeyframeRule, OdometryConfig
from gtvo.pipeline import process_sequence
from gtvo.io.outputs import evaluate, ground_truth
from gtvo.datasets.synthetic import make_synthetic_sequence


def _pose(yaw, t):
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    T[:3, 3] = t
    return T


def test_relocate_frames_moves_each_frame_with_its_keyframe():
    poses = np.stack([_pose(0.1 * i, [i, 0, 2 * i]) for i in range(6)])
    keyframes = [0, 3]
    new_kf = np.stack([poses[0], _pose(0.5, [3.5, 0.2, 6.0])])
    out = relocate_frames(poses, keyframes, new_kf)
    np.testing.assert_allclose(out[:3], poses[:3], atol=1e-12)  # frames of keyframe 0 do not move
    np.testing.assert_allclose(out[3], new_kf[1], atol=1e-12)
    for i in (4, 5):  # relative pose to the keyframe is kept
        np.testing.assert_allclose(np.linalg.inv(out[3]) @ out[i], np.linalg.inv(poses[3]) @ poses[i], atol=1e-12)


def test_synthetic_revisit_is_closed():
    seq = make_synthetic_sequence(n_frames=40, motion="loop", noise_sigma=1.0)
    vo, traj, _ = process_sequence(seq, OdometryConfig(mode="track", keyframes=KeyframeRule(max_motion=0.0),
                                                   frontend=FrontendConfig(points_per_keyframe=800)))
    keyframes = [p for p, e in enumerate(vo.estimates) if e.is_keyframe]
    res = close_loops_of_run(seq, traj, [e.index for e in vo.estimates], keyframes)
    assert res.candidates and all(res.accepted)
    # the loop ends one step before its start: closing it pulls the end back towards the truth
    drift_vo = evaluate(*ground_truth(seq, traj))["drift_percent"]
    drift_lc = evaluate(*ground_truth(seq, res.trajectory))["drift_percent"]
    assert drift_lc < drift_vo
    R = res.trajectory.poses[:, :3, :3]
    np.testing.assert_allclose(np.einsum("nji,njk->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)
