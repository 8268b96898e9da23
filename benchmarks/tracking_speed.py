"""Tracking time per frame on the real KITTI snippet, hand-rolled vs GTSAM, 500/2000/8000 points.

Keyframe = frame 0 (or every K-th frame) with high-gradient points and StereoSGBM inverse depths
(a stand-in for gtvo's own stereo depth); each following frame is tracked against it from a
constant-velocity guess. Times are CPU seconds of this process (``time.process_time``) with
one BLAS thread, so other load on the machine inflates them little; wall time is printed too.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/tracking_speed.py [KITTI_DIR]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import gtsam  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks._kitti_sgbm import load_kitti, read_gray, sgbm_keyframe_points  # noqa: E402
from gtvo.frontend.tracking import TrackingConfig, TrackingKeyframe, frame_pyramid, track_gtsam, track_handrolled  # noqa: E402

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti_stereo_sample" / "KITTI_sequence_1"


def run(folder: Path, n_points: int, frames: int = 10, keyframe_every: int = 5) -> None:
    stereo, lefts, rights, gt = load_kitti(folder)
    cfg = TrackingConfig()
    rows = {"handrolled": [], "gtsam": []}
    errs = {"handrolled": [], "gtsam": []}
    prep = []
    for solver, fn in (("handrolled", track_handrolled), ("gtsam", track_gtsam)):
        kf = None
        T_prev = gtsam.Pose3()
        T_prev2 = gtsam.Pose3()
        for i in range(frames + 1):
            left = read_gray(lefts[i])
            if i % keyframe_every == 0:
                px, d, V = sgbm_keyframe_points(left, read_gray(rights[i]), stereo, n_points)
                c0 = time.process_time()
                kf = TrackingKeyframe(stereo.left, left, px, d, V, config=cfg)
                prep.append(time.process_time() - c0)
                T_world_kf = gtsam.Pose3(gt[i]) if i == 0 else T_prev
                if i > 0:
                    continue
                T_prev = T_prev2 = T_world_kf
                continue
            guess = T_world_kf.between(T_prev.compose(T_prev2.between(T_prev)))
            c0, w0 = time.process_time(), time.perf_counter()
            pyr = frame_pyramid(left, kf.levels)
            r = fn(kf, pyr, guess)
            rows[solver].append((time.process_time() - c0, time.perf_counter() - w0, r.iterations, r.success))
            if "--verbose" in sys.argv:
                print(solver, i, r.success, r.reason, round(r.rms, 3), r.n_valid)
            T_new = T_world_kf.compose(r.T_keyframe_frame)
            e = gtsam.Pose3.Logmap(gtsam.Pose3(np.linalg.inv(gt[i - 1]) @ gt[i]).between(T_prev.between(T_new)))
            errs[solver].append((np.linalg.norm(e[3:]), np.degrees(np.linalg.norm(e[:3]))))
            T_prev2, T_prev = T_prev, T_new
            if (i + 1) % keyframe_every == 0:
                pass
    for solver in rows:
        a = np.array(rows[solver], dtype=float)
        e = np.array(errs[solver])
        print(f"{n_points:5d} pts {solver:10s}: cpu {1e3 * np.median(a[:, 0]):6.1f} ms/frame (mean {1e3 * a[:, 0].mean():6.1f}),"
              f" wall {1e3 * np.median(a[:, 1]):6.1f} ms, iters {a[:, 2].mean():4.1f}, ok {int(a[:, 3].sum())}/{len(a)},"
              f" frame-to-frame err {100 * e[:, 0].mean():.1f} cm / {e[:, 1].mean():.3f} deg")
    print(f"{n_points:5d} pts keyframe preparation: cpu {1e3 * np.median(prep):.1f} ms")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    folder = Path(args[0]) if args else DEFAULT
    for n in (500, 2000, 8000):
        run(folder, n)
