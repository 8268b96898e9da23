"""How good is the filter's predicted pose as a tracker's initial guess? KITTI 00, one run.

    PYTHONPATH=. python benchmarks/motion_model_kitti.py [--data ../shared/data/trajectory_eval_evo]

For every frame t the next planar pose (X, Z, theta) is predicted from the poses up to t by
(a) zero motion, (b) constant velocity (linear extrapolation of the last two poses) and
(c) the constant-acceleration Kalman filter (``ConstantAccelerationFilter.predict_pose(dt)``),
and compared with the pose at t+1 of the same input. Inputs: the KITTI 00 ground truth (4541
frames, 10 Hz), the ground truth with added white noise (a noisy VO), and ORB-SLAM's stereo
estimate (a real, smooth VO). Prints RMS errors of the predicted position (m) and heading (deg).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from gtvo.motion.model import ConstantAccelerationFilter, MotionNoiseConfig, planar_pose_from_T_world_cam, wrap_angle


def read_kitti_poses(path: Path) -> np.ndarray:
    """(N, 4, 4) poses of a KITTI pose file (3x4 row-major per line)."""
    rows = np.loadtxt(path).reshape(-1, 3, 4)
    T = np.tile(np.eye(4), (rows.shape[0], 1, 1))
    T[:, :3, :] = rows
    return T


def predictions(planar: np.ndarray, times: np.ndarray, noise: MotionNoiseConfig) -> dict[str, np.ndarray]:
    """Predicted pose of frame t+1 made at frame t, for t = 1 .. N-2, by each method."""
    n = len(times)
    zero = planar[1:n - 1]
    dt_prev = np.diff(times)[:-1]
    dt_next = np.diff(times)[1:]
    rate = planar[1:n - 1] - planar[0:n - 2]
    rate[:, 2] = wrap_angle(rate[:, 2])
    cv = planar[1:n - 1] + rate * (dt_next / dt_prev)[:, None]
    f = ConstantAccelerationFilter(noise, initial_rate_sigmas=(5.0, 5.0, 0.5))
    f.initialize(planar[0])
    kf = np.empty_like(cv)
    for t in range(1, n - 1):
        f.step(planar[t], times[t] - times[t - 1])
        kf[t - 1] = f.predict_pose(times[t + 1] - times[t])
    return {"zero motion": zero, "constant velocity": cv, "Kalman (const. accel.)": kf}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared/data/trajectory_eval_evo")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    times = np.loadtxt(args.data / "KITTI_00_gt_times.txt")
    gt = np.array([planar_pose_from_T_world_cam(T) for T in read_kitti_poses(args.data / "KITTI_00_gt.txt")])
    orb = np.array([planar_pose_from_T_world_cam(T) for T in read_kitti_poses(args.data / "KITTI_00_ORB.txt")])
    rng = np.random.default_rng(args.seed)
    inputs = {
        "ground truth": (gt, MotionNoiseConfig((2.0, 2.0, 0.5), (0.01, 0.01, 0.001))),
        "GT + noise 5 cm / 0.3 deg": (gt + rng.normal(0, 1, gt.shape) * [0.05, 0.05, np.radians(0.3)],
                                      MotionNoiseConfig((2.0, 2.0, 0.5), (0.05, 0.05, np.radians(0.3)))),
        "ORB-SLAM stereo estimate": (orb, MotionNoiseConfig((2.0, 2.0, 0.5), (0.01, 0.01, 0.001))),
    }
    print("| input | predictor | position RMS (m) | heading RMS (deg) |")
    print("|---|---|---|---|")
    for name, (planar, noise) in inputs.items():
        target = planar[2:]
        for method, pred in predictions(planar, times, noise).items():
            pos = np.sqrt(np.mean(np.sum((pred[:, :2] - target[:, :2]) ** 2, axis=1)))
            head = np.degrees(np.sqrt(np.mean(wrap_angle(pred[:, 2] - target[:, 2]) ** 2)))
            print(f"| {name} | {method} | {pos:.4f} | {head:.3f} |")


if __name__ == "__main__":
    main()
