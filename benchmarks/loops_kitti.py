"""Loop-detection figures on the KITTI snippet (../shared/data/kitti_stereo_sample/KITTI_sequence_1).

Prints, for every frame as a keyframe (stereo pair, ground-truth poses only for scoring):
* the time of ``add_keyframe`` and ``query`` (mean per keyframe) and of one ``verify``, also as
  ratios to a plain ORB extraction of the same image measured in the same run;
* verification of every pair (i, i - gap) for gap = 1..8: acceptance rate, inliers and the
  error of ``T_i_j`` against poses.txt (median / max translation [m] and rotation [deg]);
* ``chi2 = xi^T Lambda xi`` of the error ``xi = Log(T_i_j^-1 T_true)`` under the reported
  information (a consistent information gives a chi2 with 6 dof: median 5.3);
* the loops ``query`` reports with the default temporal window (the snippet drives straight
  60 m: there is no revisit, so every report would be an overlap beyond the window).

Then the same verification table for the RGB-D path (depth images) on TUM fr3/teddy's first 20
frames (../shared/data/rgbd_dataset_freiburg3_teddy_first20, mocap ground truth), when present.

Usage: python benchmarks/loops_kitti.py [KITTI_SEQUENCE_FOLDER [TUM_FOLDER]]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import gtsam
import numpy as np

from gtvo.datasets import read_kitti, read_tum
from gtvo.loops import LoopDetector, extract_orb

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
DEFAULT = DATA / "kitti_stereo_sample" / "KITTI_sequence_1"
DEFAULT_TUM = DATA / "rgbd_dataset_freiburg3_teddy_first20"


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    E = np.linalg.inv(T_true) @ T_est
    return float(np.linalg.norm(E[:3, 3])), float(np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(E[:3, :3])))))


def gap_table(det: LoopDetector, gt: np.ndarray, gaps: range) -> list[float]:
    """Print the verification table of pairs (i, i - gap) of keyframes 0..n-1; return verify times."""
    n = len(det)
    print("| gap | pairs | accepted | median inliers | median / max dt [m] | median / max dR [deg] | dt / distance "
          "| median chi2 |")
    print("|---|---|---|---|---|---|---|---|")
    t_verify = []
    for gap in gaps:
        dts, drs, inl, rel, chi2 = [], [], [], [], []
        pairs = range(gap, n)
        for i in pairs:
            t0 = time.perf_counter()
            loop = det.verify(i, i - gap)
            t_verify.append(time.perf_counter() - t0)
            if loop is None:
                continue
            T_true = np.linalg.inv(gt[i]) @ gt[i - gap]
            dt, dr = pose_error(loop.T_i_j, T_true)
            dts.append(dt)
            drs.append(dr)
            inl.append(loop.inliers)
            rel.append(dt / np.linalg.norm(T_true[:3, 3]))
            xi = gtsam.Pose3.Logmap(gtsam.Pose3(np.linalg.inv(loop.T_i_j) @ T_true))
            chi2.append(float(xi @ loop.information @ xi))
        if dts:
            print(f"| {gap} | {len(pairs)} | {len(dts)} | {np.median(inl):.0f} | {np.median(dts):.3f} / {max(dts):.3f} "
                  f"| {np.median(drs):.2f} / {max(drs):.2f} | {100 * np.median(rel):.1f} % | {np.median(chi2):.1f} |")
        else:
            print(f"| {gap} | {len(pairs)} | 0 | - | - | - | - | - |")
    return t_verify


def main() -> None:
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT
    seq = read_kitti(root)
    gt = seq.gt_poses
    det = LoopDetector(seq.camera)
    t_add = t_query = t_ref = 0.0
    reported = []
    for k in range(len(seq)):
        left, right = seq.left(k), seq.right(k)
        t0 = time.perf_counter()
        extract_orb(left)  # reference: one plain ORB extraction of the left image
        t_ref += time.perf_counter() - t0
        t0 = time.perf_counter()
        det.add_keyframe(k, left, right)
        t1 = time.perf_counter()
        reported += det.query(k)
        t_add += t1 - t0
        t_query += time.perf_counter() - t1
    n = len(seq)
    ref = t_ref / n
    print(f"{n} keyframes: reference ORB extraction {1e3 * ref:.1f} ms; add_keyframe {1e3 * t_add / n:.1f} ms "
          f"({t_add / n / ref:.1f}x), query {1e3 * t_query / n:.1f} ms ({t_query / n / ref:.1f}x) per keyframe "
          f"(vocabulary {det.vocabulary.n_words} words, trained online)")
    print(f"loops reported with temporal_window={det.config.temporal_window}: "
          f"{[(c.i, c.j) for c in reported] or 'none'}")
    t_verify = gap_table(det, gt, range(1, 9))
    print(f"verify: {1e3 * np.median(t_verify):.1f} ms median per pair ({np.median(t_verify) / ref:.1f}x reference)")
    tum_root = Path(sys.argv[2]) if len(sys.argv) > 2 else DEFAULT_TUM
    if tum_root.is_dir():
        tum = read_tum(tum_root)
        rgbd = LoopDetector(tum.camera)
        for k in range(len(tum)):
            rgbd.add_keyframe(k, tum.left(k), depth=tum.depth(k))
        print(f"RGB-D (depth images), {tum_root.name}, {len(tum)} keyframes:")
        gap_table(rgbd, tum.gt_poses, range(3, 19, 3))


if __name__ == "__main__":
    main()
