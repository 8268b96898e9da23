"""Loop closing of a VO run: place recognition over keyframes + robust keyframe pose graph."""

import numpy as np
import pytest

from gtvo.loops.closing import LoopClosingResult, close_loops_of_run, relocate_frames
from gtvo.config import FrontendConfig, KeyframeConfig, OdometryConfig
from gtvo.pipeline import process_sequence
from gtvo.evaluation.accuracy import evaluate, ground_truth
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.evaluation.trajectory import Trajectory


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


def test_the_summary_counts_what_loop_closing_found_and_did():
    traj = Trajectory(np.arange(4.0), np.tile(np.eye(4), (4, 1, 1)))
    res = LoopClosingResult(traj, candidates=[(3, 0), (2, 0)], accepted=[True, False], unrefined=[(3, 1)],
                            frame_hosts=np.array([0, 2, 1, 0]))
    assert res.summary() == {"loops_detected": 3, "loops_unrefined": 1, "loops_accepted": 1,
                             "loop_closure_solver": "gtsam_gnc_lm", "frames_refined": 2,
                             "frame_refinement_hosts_mean": 1.5}
    none = LoopClosingResult(traj).summary()
    assert none["loops_detected"] == 0 and none["frames_refined"] == 0 and none["frame_refinement_hosts_mean"] is None


@pytest.mark.slow
def test_synthetic_revisit_is_closed():
    seq = make_synthetic_sequence(n_frames=40, motion="loop", noise_sigma=1.0)
    vo, traj, _ = process_sequence(seq, OdometryConfig(mode="track", keyframes=KeyframeConfig(max_motion=0.0),
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


@pytest.mark.slow
def test_map_points_follow_the_keyframe_poses_they_are_given():
    seq = make_synthetic_sequence(n_frames=20, motion="forward")
    vo, _, _ = process_sequence(seq)
    assert len(vo.keyframes) >= 2
    G = _pose(0.3, [1.0, -0.5, 2.0])
    moved = vo.map_points({kf.index: G @ kf.T_world_cam.matrix() for kf in vo.keyframes})
    own = vo.map_points()
    assert moved.written == own.written and own.written > 0
    np.testing.assert_allclose(moved.points, own.points @ G[:3, :3].T + G[:3, 3], atol=1e-9)
    # a keyframe not in the mapping keeps its own pose
    np.testing.assert_allclose(vo.map_points({}).points, own.points)


@pytest.mark.slow
def test_run_with_loop_closure_refines_frames_and_maps_on_the_closed_keyframes(tmp_path, monkeypatch):
    from gtvo.io.trajectory_files import read_tum
    from gtvo.odometry.result import OdometryResult
    from gtvo.pipeline import TRACKED_OUTCOMES, run

    seq = make_synthetic_sequence(n_frames=60, motion="loop", seed=2)
    seen = {}
    own_map_points = OdometryResult.map_points

    def spy(self):
        seen["odo"] = self
        return own_map_points(self)

    monkeypatch.setattr(OdometryResult, "map_points", spy)
    report = run(seq, out=tmp_path / "out", loop_closure=True)
    odo = seen["odo"]
    assert report["loops_accepted"] >= 1
    assert report["frames_refined"] == sum(e.outcome in TRACKED_OUTCOMES for e in odo.estimates) > 0
    assert report["frame_refinement_hosts_mean"] >= 1
    closed = read_tum(tmp_path / "out" / "trajectory_loop_closed.tum")
    by_time = {round(float(t), 6): P for t, P in zip(closed.timestamps, closed.poses)}
    moved = 0
    for kf in odo.keyframes:  # the map's keyframe poses are the loop-closed trajectory's
        T = odo.map_poses[kf.index]
        np.testing.assert_allclose(T, by_time[round(float(seq.timestamps[kf.index]), 6)], atol=1e-5)
        moved += not np.allclose(T, kf.T_world_cam, atol=1e-6)
    assert moved > 0
