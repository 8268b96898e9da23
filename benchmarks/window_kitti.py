"""Sliding-window odometry on the KITTI snippet: accuracy against tracking alone, and window speed.

Accuracy (``accuracy``): the whole snippet through :func:`gtvo.pipeline.process_sequence` in
``track`` mode and in ``window`` mode (window solver GTSAM and hand-rolled), same frames, same
run; prints ATE RMSE (SE(3)-aligned), end-point drift (% of path), frame-to-frame RPE, seconds
per frame and the mean time per window optimisation.

Synthetic (``synthetic``): the same comparison on the demo's synthetic sequence (exact ground truth).

Speed (``speed``): one window of 7 keyframes (frames 0, 2, ..., 12, tracked poses perturbed by
the tracker's typical error) with 500 / 1000 / 2000 / 4000 points per keyframe, optimised by
both solvers with a fixed number of iterations (6), fastest of 3 runs; prints seconds per window optimisation and
per iteration, and the ratio to 500 points (linear growth: ratio ~ points / 500).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/window_kitti.py \
        [accuracy|speed|synthetic|all] [KITTI_DIR]

Before/after (``compare``): the ``speed`` and ``accuracy`` parts of this script run as
subprocesses in another checkout of gtvo (e.g. ``git worktree add /tmp/gtvo-old <commit>``)
and in this one, alternately (old, new, old, new for ``speed``), so that both are measured under
the same machine load:

    python benchmarks/window_kitti.py compare /tmp/gtvo-old [KITTI_DIR] [speed,speed,accuracy]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import copy  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Sequence  # noqa: E402

import gtsam  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from factors.photometric import GradientImage  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402
from gtvo.frontend import init_keyframe_points  # noqa: E402
from gtvo.core.image import to_float_gray  # noqa: E402
from gtvo.config import OdometryConfig, SolverConfig  # noqa: E402
from gtvo.pipeline import process_sequence  # noqa: E402
from gtvo.evaluation.accuracy import evaluate  # noqa: E402
from gtvo.evaluation.trajectory import Trajectory  # noqa: E402
from gtvo.window import (WindowConfig, WindowKeyframe, WindowMembers, WindowProblem, WindowSettings,  # noqa: E402
                         solve_gtsam, solve_handrolled)

REPEATS = 3
DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti_stereo_sample" / "KITTI_sequence_1"


def accuracy(path: Path) -> None:
    seq = open_sequence(path)
    ref = Trajectory(np.asarray(seq.timestamps, dtype=float), np.asarray(seq.gt_poses), name="gt")
    rows = [("track", OdometryConfig(mode="track")),
            ("window gtsam", OdometryConfig(mode="window", solver=SolverConfig(window="gtsam"))),
            ("window handrolled", OdometryConfig(mode="window", solver=SolverConfig(window="handrolled"))),
            ("window fixed_lag", OdometryConfig(mode="window", window=WindowConfig(backend="fixed_lag")))]
    print(f"{'mode':<20} {'ATE m':>7} {'drift %':>8} {'RPE m':>7} {'s/frame':>8} {'kf':>4} {'windows':>8} "
          f"{'s/window':>9} {'it/window':>9}")
    for name, cfg in rows:
        vo, traj, info = process_sequence(seq, cfg)
        m = evaluate(traj, ref)
        sw = info.get("window_seconds_mean")
        print(f"{name:<20} {m['ate_rmse_m']:7.4f} {m['drift_percent']:8.3f} {m['rpe_trans_rmse_m']:7.4f} "
              f"{info['seconds'] / info['frames']:8.3f} {info['keyframes']:4d} "
              f"{info.get('window_optimisations', 0):8d} {sw if sw is not None else float('nan'):9.3f} "
              f"{info.get('window_iterations_mean') or float('nan'):9.2f}")


def synthetic() -> None:
    """The demo's synthetic sequence (30 frames, exact ground truth): both modes, both window solvers."""
    from gtvo.datasets.synthetic import make_synthetic_sequence  # noqa: PLC0415

    seq = make_synthetic_sequence()
    ref = Trajectory(np.asarray(seq.timestamps, dtype=float), np.asarray(seq.gt_poses), name="gt")
    print(f"{'synthetic':<20} {'ATE m':>7} {'drift %':>8} {'s/frame':>8} {'kf':>4}")
    for name, cfg in [("track", OdometryConfig(mode="track")),
                      ("window gtsam", OdometryConfig(mode="window", solver=SolverConfig(window="gtsam"))),
                      ("window handrolled", OdometryConfig(mode="window", solver=SolverConfig(window="handrolled")))]:
        vo, traj, info = process_sequence(seq, cfg)
        m = evaluate(traj, ref)
        print(f"{name:<20} {m['ate_rmse_m']:7.4f} {m['drift_percent']:8.3f} {info['seconds'] / info['frames']:8.3f} "
              f"{info['keyframes']:4d}")


def _window(seq, points: int, frames=range(0, 14, 2)) -> list[WindowKeyframe]:
    rng = np.random.default_rng(1)
    kfs = []
    for i in frames:
        fr = seq.frame(i)
        left = to_float_gray(fr.left, "left")
        right = to_float_gray(fr.right, "right")
        pts = init_keyframe_points(left, right, seq.camera, target=points)
        T = gtsam.Pose3(np.asarray(seq.gt_poses[i]))
        if kfs:  # the tracker's typical error on this snippet: ~0.2 mrad, ~1 cm
            T = T.retract(np.r_[rng.normal(0, 2e-4, 3), rng.normal(0, 0.01, 3)])
        kfs.append(WindowKeyframe(i, T, np.zeros(2), GradientImage(left), pts.pixels, pts.inverse_depth,
                                  pts.variance, right=GradientImage(right)))
    return kfs


def speed(path: Path) -> None:
    seq = open_sequence(path)
    cam = seq.camera
    cfg = WindowConfig(max_iterations=6, relative_tolerance=0.0)
    print(f"{'points/kf':>9} {'actual':>7} {'pairs':>7} {'gtsam s':>8} {'it':>3} {'s/it':>6} {'ratio':>6} "
          f"{'hand s':>7} {'it':>3} {'s/it':>6} {'ratio':>6}")
    base = None
    for n in (500, 1000, 2000, 4000):
        kfs = _window(seq, n)
        actual = int(np.mean([len(k) for k in kfs]))
        tg = th = np.inf
        for _ in range(REPEATS):  # the machine is shared: keep the fastest of a few runs
            a, b = copy.deepcopy(kfs), copy.deepcopy(kfs)
            t0 = time.perf_counter()
            ra = solve_gtsam(WindowProblem.build(WindowMembers(cam.left, cam.baseline, a), WindowSettings(cfg)))
            tg = min(tg, time.perf_counter() - t0)
            t0 = time.perf_counter()
            rb = solve_handrolled(WindowProblem.build(WindowMembers(cam.left, cam.baseline, b), WindowSettings(cfg)))
            th = min(th, time.perf_counter() - t0)
        per = (tg / max(ra.iterations, 1), th / max(rb.iterations, 1))
        base = base or per
        print(f"{n:9d} {actual:7d} {ra.n_residuals:7d} {tg:8.3f} {ra.iterations:3d} {per[0]:6.3f} "
              f"{per[0] / base[0]:6.2f} {th:7.3f} {rb.iterations:3d} {per[1]:6.3f} {per[1] / base[1]:6.2f}")


def compare(old_tree: Path, path: Path, parts: Sequence[str] = ("speed", "speed", "accuracy")) -> None:
    """Run each of ``parts`` in ``old_tree``, then in this checkout (default: ``speed`` twice, ``accuracy``)."""
    import subprocess  # noqa: PLC0415

    here = Path(__file__).resolve().parents[1]
    for what in parts:
        for name, tree in (("old", Path(old_tree).resolve()), ("new", here)):
            out = subprocess.run([sys.executable, str(tree / "benchmarks" / "window_kitti.py"), what, str(path)],
                                 cwd=tree, capture_output=True, text=True, check=True).stdout
            print(f"--- {what}, {name} ({tree})\n{out}", flush=True)


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "all"
    if what == "compare":
        compare(Path(sys.argv[2]), Path(sys.argv[3]) if len(sys.argv) > 3 else DEFAULT,
                sys.argv[4].split(",") if len(sys.argv) > 4 else ("speed", "speed", "accuracy"))
        sys.exit(0)
    data = Path(sys.argv[2]) if len(sys.argv) > 2 else DEFAULT
    if what in ("speed", "all"):
        speed(data)
    if what in ("accuracy", "all"):
        accuracy(data)
    if what in ("synthetic", "all"):
        synthetic()
