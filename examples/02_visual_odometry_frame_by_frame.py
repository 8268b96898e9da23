"""
Visual odometry frame by frame, as a program that imports gtvo as a backend would run it: open a
sequence, feed its frames one at a time to gtvo.VisualOdometry, read each frame's estimate.

The sequence is KITTI_sequence_1 of the shared data when it is there ($GTVO_SHARED_DATA, or
../shared/data beside the checkout), else gtvo's synthetic stereo sequence written to a temporary
folder in the KITTI layout (what `gtvo synthetic --out DIR` writes).
Run from the checkout's root: python examples/02_visual_odometry_frame_by_frame.py
"""

import os
import tempfile
from pathlib import Path

import numpy as np

import gtvo
from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti


def sequence_folder(scratch):
    """KITTI_sequence_1 of the shared data if present, else a synthetic sequence written into ``scratch``."""
    shared = Path(os.environ.get("GTVO_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    kitti = shared / "kitti_stereo_sample" / "KITTI_sequence_1"
    if kitti.is_dir():
        return kitti
    return write_sequence_kitti(make_synthetic_sequence(n_frames=40), Path(scratch) / "synthetic")


def main():
    """Main runner."""
    with tempfile.TemporaryDirectory() as scratch:
        # 1. Open the sequence: lazy, each frame's images are read when the frame is asked for
        seq = gtvo.open_sequence(sequence_folder(scratch))
        print(f"{seq.name}: {len(seq)} frames {seq.pinhole.width}x{seq.pinhole.height}, "
              f"baseline {seq.camera.baseline:.3f} m")

        # 2. Create the odometry: its settings are one tree, gtvo.OdometryConfig (docs/configuration.md)
        config = gtvo.OdometryConfig(mode="window", solver="gtsam")
        vo = gtvo.VisualOdometry(seq.camera, config)

        # 3. Feed the frames one at a time; each returns the frame's estimate (pose, outcome)
        for frame in seq:
            estimate = vo.process(frame)
            if frame.index % 10 == 0:
                x, y, z = estimate.T_world_cam[:3, 3]
                print(f"frame {frame.index:3d} {estimate.outcome.name:<13} position ({x:6.2f}, {y:6.2f}, {z:6.2f}) m")

        # 4. Finish: the last keyframes' window optimisation
        vo.finish()

        # 5. The trajectory, with the window's optimised keyframes, against the ground truth
        trajectory = vo.trajectory()
        gt_world_cam = np.linalg.inv(seq.gt_poses[0]) @ seq.gt_poses  # ground truth from the first camera
        errors = np.linalg.norm(trajectory.positions - gt_world_cam[:, :3, 3], axis=1)
        print(f"{len(trajectory)} poses, {len(vo.keyframes)} keyframes, path {trajectory.path_length():.1f} m")
        print(f"position error: final {errors[-1]:.3f} m ({100 * errors[-1] / trajectory.path_length():.2f} % of "
              f"the path), largest {errors.max():.3f} m (no alignment)")

        # 6. The last keyframe's pose covariance (6x6, GTSAM's tangent order: rotation, then translation)
        sigmas = np.sqrt(np.diag(vo.covariance(vo.keyframes[-1])))
        print(f"last keyframe sigma: rotation {np.degrees(sigmas[:3]).max():.3f} deg, "
              f"translation {sigmas[3:].max() * 100:.2f} cm")


if __name__ == "__main__":
    main()
