"""Linearisation cost of each factor, and one GTSAM LM iteration: one CustomFactor per point
versus the per-host smart factor (factors.smart.HostPointsFactor), on real KITTI images.

Host = frame 0 of the KITTI snippet with N high-gradient points and StereoSGBM inverse depths,
targets = frames 1 and 2 at their ground-truth poses slightly perturbed. Per-point design: 2N
PhotometricFactors + N native depth priors, Values = 3 poses + N inverse depths. Smart design:
one HostPointsFactor, Values = 3 poses. Wall-clock seconds (the machine is shared: compare the
two designs within one run).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/factors_linearize.py [KITTI_DIR] [--all]

--all also runs the per-point design at N = 8000 (minutes).
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
from factors.gtsam_factors import PhotometricBatchFactor, PhotometricFactor, StereoFactor  # noqa: E402
from gtvo.core.keys import affine_key as A  # noqa: E402
from gtvo.core.keys import inverse_depth_key as D  # noqa: E402
from gtvo.core.keys import pose_key as X  # noqa: E402
from gtvo.core.keys import right_affine_key as RA  # noqa: E402
from factors.photometric import GradientImage  # noqa: E402
from factors.smart import HostPointsFactor  # noqa: E402
from factors.smoothness import InverseDepthSmoothnessFactor, MotionSmoothnessFactor  # noqa: E402
DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti_stereo_sample" / "KITTI_sequence_1"
PERTURB = np.array([0.002, -0.001, 0.001, 0.02, -0.01, 0.03])


def timeit(fn, repeat: int = 3) -> float:
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def setup(folder: Path, n: int):
    stereo, lefts, rights, gt = load_kitti(folder)
    host = read_gray(lefts[0])
    px, d, V = sgbm_keyframe_points(host, read_gray(rights[0]), stereo, n)
    imgs = [GradientImage(host), GradientImage(read_gray(lefts[1])), GradientImage(read_gray(lefts[2]))]
    poses = [gtsam.Pose3(gt[i]) for i in range(3)]
    v = gtsam.Values()
    v.insert(X(0), poses[0])
    v.insert(X(1), poses[1].retract(PERTURB))
    v.insert(X(2), poses[2].retract(-PERTURB))
    return stereo, px, d, V, imgs, v, GradientImage(read_gray(rights[0]))


def per_factor(folder: Path) -> None:
    stereo, px, d, V, imgs, v, right = setup(folder, 2000)
    cam = stereo.left
    vv = gtsam.Values(v)
    vv.insert(D(0), float(d[0]))
    vv.insert(D(1), float(d[1]))
    vv.insert(A(0), np.zeros(2))
    vv.insert(A(1), np.zeros(2))
    vv.insert(RA(0), np.zeros(2))
    rows = [
        ("PhotometricFactor (1 point, 8 px, affines)",
         PhotometricFactor(X(0), X(1), D(0), cam, px[0], imgs[0], imgs[1], V[0], affine_host_key=A(0),
                           affine_target_key=A(1)), 1),
        ("StereoFactor (1 point)", StereoFactor(D(0), RA(0), cam, stereo.baseline, px[0], imgs[0], right), 1),
        ("InverseDepthSmoothnessFactor", InverseDepthSmoothnessFactor(D(0), D(1)), 1),
        ("MotionSmoothnessFactor", MotionSmoothnessFactor(X(0), X(1), X(2)), 1),
        ("PhotometricBatchFactor (2000 points, fixed depths)",
         PhotometricBatchFactor(X(1), cam, px, d, imgs[0], imgs[1], V, host_key=X(0)), 2000),
        ("HostPointsFactor (2000 points x 2 targets)",
         HostPointsFactor(X(0), [X(1), X(2)], cam, px, d, imgs[0], imgs[1:], V), 4000),
    ]
    print("## time per linearisation, called from Python (graph.linearize path, no Values copy)")
    for name, f, per in rows:
        t = timeit(lambda: f.linearize(vv), 5)
        print(f"{name:55s} {1e6 * t:10.1f} us   ({1e6 * t / per:7.2f} us per point-target)")


def lm_iteration(folder: Path, n: int, skip_per_point: bool) -> None:
    stereo, px, d, V, imgs, v, _ = setup(folder, n)
    cam = stereo.left
    prior = gtsam.PriorFactorPose3(X(0), v.atPose3(X(0)), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6))
    scale = gtsam.PriorFactorPose3(X(1), v.atPose3(X(1)), gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.ones(3), 1e-3 * np.ones(3)]))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(1)
    # smart
    t0 = time.perf_counter()
    f = HostPointsFactor(X(0), [X(1), X(2)], cam, px, d, imgs[0], imgs[1:], V)
    g = gtsam.NonlinearFactorGraph()
    g.add(f)
    g.add(prior)
    g.add(scale)
    t_build = time.perf_counter() - t0
    e0 = g.error(v)  # before any linearisation: the cost at the initial depths
    t0 = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(g, v, params)
    opt.iterate()
    t_smart = time.perf_counter() - t0
    e_smart = (e0, opt.error())
    line = (f"N={n:5d}: smart factor 1 LM iteration {t_smart:8.3f} s (build {t_build:.3f} s), "
            f"error {e_smart[0]:.4g} -> {e_smart[1]:.4g}")
    if skip_per_point:
        print(line + ";  per-point: skipped (see extrapolation)")
        return
    t0 = time.perf_counter()
    g2 = gtsam.NonlinearFactorGraph()
    g2.add(prior)
    g2.add(scale)
    v2 = gtsam.Values(v)
    for j in range(n):
        v2.insert(D(j), float(d[j]))
        g2.add(gtsam.PriorFactorDouble(D(j), float(d[j]), gtsam.noiseModel.Isotropic.Sigma(1, float(np.sqrt(V[j])))))
        for t in (1, 2):
            g2.add(PhotometricFactor(X(0), X(t), D(j), cam, px[j], imgs[0], imgs[t], float(V[j])))
    t_build2 = time.perf_counter() - t0
    e0 = g2.error(v2)
    t0 = time.perf_counter()
    opt2 = gtsam.LevenbergMarquardtOptimizer(g2, v2, params)
    opt2.iterate()
    t_pp = time.perf_counter() - t0
    t_lin = timeit(lambda: g2.linearize(v2), 1)
    print(line + f";  per-point ({2 * n} CustomFactors, {n + 3} variables) {t_pp:8.3f} s "
          f"(build {t_build2:.2f} s; graph.linearize from Python {t_lin:.3f} s), error {e0:.4g} -> "
          f"{opt2.error():.4g};  ratio {t_pp / t_smart:.0f}x")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    folder = Path(args[0]) if args else DEFAULT
    per_factor(folder)
    print("## one LM iteration (host + 2 targets)")
    for n in (500, 2000, 8000):
        lm_iteration(folder, n, skip_per_point=(n > 2000 and "--all" not in sys.argv))
