"""Tracking-only odometry over the whole KITTI snippet (a preview of `gtvo run --mode track`).

Each frame is tracked against the latest keyframe (SGBM stand-in depths, 2000 points) from a
constant-velocity guess; a new keyframe is taken when fewer than ``KEYFRAME_VALID`` of the
keyframe's points stay valid or tracking reports failure (then the frame is re-tracked against
the previous frame promoted to keyframe); each tracking tries the constant-velocity guess,
then no motion, then the keyframe pose (`track_with_guesses`, accepting a result at once when its
RMS is below 1.3x the previous frame's, else the lowest-cost success); a frame that still fails keeps the
motion-model prediction. Prints ATE (RMSE after SE(3) alignment) and end-point
drift (% of path length) for both solvers.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/tracking_kitti_sequence.py [KITTI_DIR]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import gtsam  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks._kitti_sgbm import load_kitti, read_gray, sgbm_keyframe_points  # noqa: E402
from gtvo.evaluation.metrics import umeyama_alignment  # noqa: E402
from gtvo.frontend.tracking import (TrackingConfig, TrackingKeyframe, frame_pyramid, track_gtsam, track_handrolled,  # noqa: E402
                           track_with_guesses)

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti_stereo_sample" / "KITTI_sequence_1"
CONFIG = TrackingConfig(cost_tolerance=float(os.environ.get("GTVO_COST_TOL", "1e-3")))
ACCEPT_RMS_FACTOR = 1.3
KEYFRAME_VALID = float(os.environ.get("GTVO_KEYFRAME_VALID", "1.01"))


def umeyama_ate(est: np.ndarray, gt: np.ndarray) -> float:
    """RMSE of positions after the best rigid (no scale) alignment of est onto gt."""
    S = umeyama_alignment(est, gt, with_scale=False)
    return float(np.sqrt(np.mean(np.sum((S.apply(est) - gt) ** 2, axis=1))))


def run(folder: Path, solver, n_points: int = 2000) -> None:
    stereo, lefts, rights, gt = load_kitti(folder)

    def make_kf(i: int) -> TrackingKeyframe:
        left = read_gray(lefts[i])
        px, d, V = sgbm_keyframe_points(left, read_gray(rights[i]), stereo, n_points)
        return TrackingKeyframe(stereo.left, left, px, d, V, config=CONFIG)

    poses = [gtsam.Pose3(gt[0])]
    kf, kf_index, T_world_kf = make_kf(0), 0, poses[0]
    n_kf, failures, cpu = 1, 0, 0.0
    affine = np.zeros(2)
    accept_rms = None
    for i in range(1, len(lefts)):
        prev = poses[-1]
        pred = prev.compose(poses[-2].between(prev)) if len(poses) > 1 else prev
        pyr = frame_pyramid(read_gray(lefts[i]), kf.levels)
        c0 = time.process_time()
        guesses = [T_world_kf.between(pred), T_world_kf.between(prev), gtsam.Pose3()]
        r = track_with_guesses(kf, pyr, guesses, affine, solver, accept_rms)
        cpu += time.process_time() - c0
        if not r.success or r.n_valid < KEYFRAME_VALID * len(kf.inverse_depth):
            if kf_index != i - 1:  # re-track against the previous frame as the new keyframe
                kf, kf_index, T_world_kf = make_kf(i - 1), i - 1, prev
                n_kf += 1
                affine = np.zeros(2)
                r = track_with_guesses(kf, pyr, [T_world_kf.between(pred), T_world_kf.between(prev),
                                                 gtsam.Pose3(gtsam.Rot3(), T_world_kf.between(pred).translation())],
                                       affine, solver, accept_rms)
                if "--verbose" in sys.argv:
                    g_err = gtsam.Pose3.Logmap(gtsam.Pose3(np.linalg.inv(gt[i - 1]) @ gt[i]).between(T_world_kf.between(pred)))
                    print("   re-tracked against", kf_index, "guess error", np.round(g_err, 4), affine, r.iterations)
            if not r.success:
                failures += 1
        if not r.success:  # keep the motion model's prediction rather than a failed pose
            r.T_keyframe_frame = T_world_kf.between(pred)
        affine = r.affine
        if r.success:
            accept_rms = ACCEPT_RMS_FACTOR * r.rms
        if "--verbose" in sys.argv:
            print(i, kf_index, r.success, r.reason, r.n_valid, r.iterations, np.round(r.T_keyframe_frame.translation(), 3))
        poses.append(T_world_kf.compose(r.T_keyframe_frame))
    est = np.array([p.translation() for p in poses])
    ref = gt[:, :3, 3]
    length = float(np.sum(np.linalg.norm(np.diff(ref, axis=0), axis=1)))
    drift = 100.0 * float(np.linalg.norm(est[-1] - ref[-1])) / length
    print(f"{solver.__name__:16s}: {len(poses)} frames, {n_kf} keyframes, {failures} failures, "
          f"ATE {umeyama_ate(est, ref):.3f} m, end-point drift {drift:.2f} % of {length:.1f} m, "
          f"tracking cpu {1e3 * cpu / (len(poses) - 1):.1f} ms/frame")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    folder = Path(args[0]) if args else DEFAULT
    for fn in (track_handrolled, track_gtsam):
        run(folder, fn)
