"""Odometry calibration figures: real Freiburg data and synthetic joint calibration.

Usage: python benchmarks/odometry_calibration_bench.py [--data DIR] [--plot OUT.png] [--sizes 200 1000 2000]

Prints markdown tables (timings as ratios to a reference measured in the same run, since the
machine is shared).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from gtvo.wheel_calibration import (PosePrior, apply_linear, fit_diff_drive, fit_diff_drive_gtsam, fit_linear,
                              fit_linear_gtsam, integrate_motions, joint_calibration, position_rmse, read_motion_pair)
from gtvo.wheel_calibration.plot import plot_trajectories

README_X = np.array([[1.00185, 4.686154, -0.468625], [0.007172, 0.445732, 0.052008], [0.004872, -1.95554, 1.218938]])
X_TRUE = np.array([[1.05, 0.10, 0.02], [0.01, 0.95, 0.03], [0.005, -0.05, 0.90]])


def timed(fn, repeat: int = 3):
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


def real_data(data: Path, plot: Path | None, baseline: float) -> None:
    d = data / "odometry_calibration" / "robot_mapping_odom_calib"
    odom, ref = read_motion_pair(d / "odom_motions", d / "scanmatched_motions")
    lin, t_lin = timed(lambda: fit_linear(odom, ref))
    lin_g, t_lin_g = timed(lambda: fit_linear_gtsam(odom, ref))
    dd, t_dd = timed(lambda: fit_diff_drive(odom, ref, baseline))
    dd_g, t_dd_g = timed(lambda: fit_diff_drive_gtsam(odom, ref, baseline))
    np.set_printoptions(precision=6, suppress=True)
    print(f"## real data ({len(odom)} motions)\n")
    print(f"X (hand-rolled) =\n{lin.X}\ndet = {np.linalg.det(lin.X):.6f}; max |X - README X| = "
          f"{np.abs(lin.X - README_X).max():.2e}; max |X_gtsam - X| / max|X| = "
          f"{np.abs(lin_g.X - lin.X).max() / np.abs(lin.X).max():.2e}")
    print(f"diff-drive (b0 = {baseline} m): k_L, k_R, k_b = {dd.params} +- {np.sqrt(np.diag(dd.covariance))}; "
          f"GTSAM differs by {np.abs(dd_g.params - dd.params).max():.2e}\n")
    gt = integrate_motions(ref)
    rows = [("raw odometry", odom, 0), ("linear X", lin.apply(odom), 9), ("diff-drive", dd.apply(odom), 3)]
    print("| motions | parameters | per-motion RSS | residual rms dx, dy, dtheta | trajectory RMSE vs reference (m) | end-point error (m) |")
    print("|---|---|---|---|---|---|")
    for name, m, k in rows:
        e = ref - m
        traj = integrate_motions(m)
        print(f"| {name} | {k} | {np.sum(e * e):.4f} | {', '.join(f'{v:.4g}' for v in np.sqrt(np.mean(e * e, 0)))} | "
              f"{position_rmse(traj, gt, align=False):.2f} | {np.linalg.norm(traj[-1, :2] - gt[-1, :2]):.2f} |")
    print("\n| solver | time / hand-rolled linear |\n|---|---|")
    for name, t in [("linear, hand-rolled", t_lin), ("linear, GTSAM LM + Marginals (2000 CustomFactors)", t_lin_g),
                    ("diff-drive, hand-rolled GN", t_dd), ("diff-drive, GTSAM LM + Marginals", t_dd_g)]:
        print(f"| {name} | {t / t_lin:.1f} |")
    print(f"\n(hand-rolled linear: {t_lin * 1e3:.1f} ms in this run)\n")
    if plot is not None:
        plot_trajectories(plot, {"raw odometry": odom, "calibrated (linear X)": lin.apply(odom),
                                 "calibrated (diff-drive)": dd.apply(odom), "reference (scan matching)": ref},
                          title="Freiburg odometry calibration: integrated motions")
        print(f"plot: {plot}\n")


def synthetic_joint(n: int, seed: int = 5) -> None:
    rng = np.random.default_rng(seed)
    true_u = np.column_stack([rng.uniform(0.3, 0.7, n), rng.normal(0, 0.1, n), rng.normal(0, 0.15, n)])
    gt = integrate_motions(true_u)
    sig = (2e-3, 2e-3, 1e-3)
    raw = apply_linear(np.linalg.inv(X_TRUE), true_u) + rng.normal(0, sig, (n, 3))
    priors = [PosePrior(i, tuple(gt[i] + rng.normal(0, [0.05, 0.05, 0.02])), (0.05, 0.05, 0.02))
              for i in range(0, n + 1, 10)]
    t0 = time.perf_counter()
    uncal = joint_calibration(raw, sig, priors, calibrate=False, marginals=False)
    t_uncal = time.perf_counter() - t0
    t0 = time.perf_counter()
    joint = joint_calibration(raw, sig, priors, initial_poses=uncal.poses, marginals=True)
    t_joint = time.perf_counter() - t0
    se = np.sqrt(np.diag(joint.covariance)).reshape(3, 3)
    err = np.abs(joint.X - X_TRUE)
    print(f"| {n} | {err.max():.4f} | {np.max(err / se):.2f} | {position_rmse(integrate_motions(raw, gt[0]), gt, False):.2f} | "
          f"{position_rmse(uncal.poses, gt, False):.3f} | {position_rmse(joint.poses, gt, False):.3f} | "
          f"{joint.iterations} | {joint.seconds / max(joint.iterations, 1) / (uncal.seconds / max(uncal.iterations, 1)):.0f} | "
          f"{t_joint / t_uncal:.0f} | {t_uncal:.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1].parent / "shared" / "data")
    ap.add_argument("--plot", type=Path, default=None)
    ap.add_argument("--baseline", type=float, default=0.5)
    ap.add_argument("--sizes", type=int, nargs="*", default=[200, 1000, 2000])
    args = ap.parse_args()
    real_data(args.data, args.plot, args.baseline)
    print("## joint calibration (synthetic, pose priors every 10 poses)\n")
    print("| motions | max abs X error | max error / marginal sd | ATE dead reckoning raw (m) | ATE pose graph, X = I (m) | "
          "ATE joint (m) | LM iterations | time per iteration joint / native graph | total joint / native graph | native graph (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for n in args.sizes:
        synthetic_joint(n)


if __name__ == "__main__":
    main()
