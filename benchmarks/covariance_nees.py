"""Are the window's pose covariances honest? NEES of the keyframe poses on noisy synthetic sequences.

For each seed: a synthetic stereo sequence with i.i.d. image noise (``make_synthetic_sequence``),
gtvo in window mode, then for every keyframe but the first (the gauge) the error
``xi = Log(T_gt^-1 T_est)`` (GTSAM's tangent order ``[rotation, translation]``, right perturbation:
the convention of the covariances) after aligning the first keyframe's ground-truth pose onto its
estimate, and ``NEES = xi^T P^-1 xi`` with ``P = vo.covariance(keyframe)``. A consistent estimator
has mean NEES 6 (3 for the position and rotation blocks alone) and 95 % of the NEES below
chi2(6, 0.95) = 12.59. Prints one line per seed and a Markdown summary: mean NEES, its ratio to 6
(the optimism factor: the factor by which the covariances would have to be inflated), the
fraction inside the 95 % bound, and the same for the position and rotation blocks.

    python benchmarks/covariance_nees.py [--seeds 20] [--frames 30] [--noise 2] [--size 160x120]
        [--solver gtsam] [--motion forward] [--inflation 1.0] [--iterations 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
if str(REPO_ROOT) not in sys.path:  # run as `python benchmarks/<script>.py`
    sys.path.insert(0, str(REPO_ROOT))

import gtsam  # noqa: E402
import numpy as np  # noqa: E402

from gtvo.config import OdometryConfig, SolverConfig  # noqa: E402
from gtvo.datasets.synthetic import make_synthetic_sequence  # noqa: E402
from gtvo.odometry import VisualOdometry  # noqa: E402
from gtvo.window import WindowConfig  # noqa: E402

#: chi-square 95 % quantiles for 6 and 3 degrees of freedom
CHI2_95 = {6: 12.591587243743977, 3: 7.814727903251178}


def keyframe_errors(vo: VisualOdometry, gt_poses: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(xi, P)`` of every keyframe with a covariance, except the first (the gauge), in keyframe order."""
    kfs = vo.keyframes
    T0 = kfs[0].T_world_cam
    align = T0.compose(gtsam.Pose3(gt_poses[kfs[0].index]).inverse())  # ground truth onto the first estimate
    out = []
    for kf in kfs[1:]:
        P = vo.covariance(kf)
        if P is None:
            continue
        T_gt = align.compose(gtsam.Pose3(gt_poses[kf.index]))
        out.append((np.asarray(gtsam.Pose3.Logmap(T_gt.between(kf.T_world_cam)), dtype=float), P))
    return out


def nees(xi: np.ndarray, P: np.ndarray, block: slice = slice(0, 6)) -> float:
    """``xi^T P^-1 xi`` on ``block`` of the tangent (0:3 rotation, 3:6 translation)."""
    e = xi[block]
    return float(e @ np.linalg.solve(P[block, block], e))


def summary(values: list[float], dof: int) -> tuple[float, float, float, float]:
    """(mean NEES, mean / dof, fraction below the 95 % chi-square bound, the inflation that would put
    95 % inside it: the 95th percentile of the NEES over the bound)."""
    v = np.asarray(values, dtype=float)
    return (float(v.mean()), float(v.mean() / dof), float(np.mean(v <= CHI2_95[dof])),
            float(np.percentile(v, 95) / CHI2_95[dof]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20, help="number of seeds (0..N-1)")
    ap.add_argument("--frames", type=int, default=30, help="frames per sequence")
    ap.add_argument("--noise", type=float, default=2.0, help="image noise sigma (grey levels)")
    ap.add_argument("--size", default="160x120", help="image size WxH")
    ap.add_argument("--solver", choices=("gtsam", "handrolled"), default="gtsam", help="window solver")
    ap.add_argument("--motion", choices=("forward", "loop", "turn"), default="forward")
    ap.add_argument("--inflation", type=float, default=1.0, help="multiply every covariance by this first")
    ap.add_argument("--iterations", type=int, default=WindowConfig().max_iterations,
                    help="the window's LM iterations (default: WindowConfig's)")
    args = ap.parse_args(argv)
    w, h = (int(x) for x in args.size.lower().split("x"))
    rows: dict[str, list[float]] = {"all": [], "rot": [], "pos": [], "first": [], "later": []}
    t0 = time.perf_counter()
    for seed in range(args.seeds):
        seq = make_synthetic_sequence(args.frames, width=w, height=h, noise_sigma=args.noise, seed=seed,
                                      motion=args.motion)
        vo = VisualOdometry(seq.camera, OdometryConfig(mode="window", solver=SolverConfig(window=args.solver),
                                                       window=WindowConfig(max_iterations=args.iterations)))
        for i in range(len(seq)):
            vo.process(seq.frame(i))
        vo.finish()
        errs = keyframe_errors(vo, np.asarray(seq.gt_poses))
        n_all = [nees(xi, args.inflation * P) for xi, P in errs]
        rows["all"] += n_all
        size = vo.config.window.size  # keyframes 1..size-1 share the first window: no marginal prior yet
        rows["first"] += n_all[:size - 1]
        rows["later"] += n_all[size - 1:]
        rows["rot"] += [nees(xi, args.inflation * P, slice(0, 3)) for xi, P in errs]
        rows["pos"] += [nees(xi, args.inflation * P, slice(3, 6)) for xi, P in errs]
        pos_err = np.median([np.linalg.norm(xi[3:]) for xi, _ in errs]) if errs else float("nan")
        pos_sig = np.median([np.sqrt(np.trace(P[3:, 3:])) for _, P in errs]) if errs else float("nan")
        print(f"seed {seed}: {len(errs)} keyframes, mean NEES {np.mean(n_all):.2f}, median position error "
              f"{1000 * pos_err:.2f} mm, median position sigma {1000 * pos_sig:.2f} mm", file=sys.stderr, flush=True)
    print(f"\n{args.seeds} seeds x {args.frames} frames, {w}x{h}, noise {args.noise:g}, {args.motion}, "
          f"{args.solver} window solver, {args.iterations} LM iterations, inflation {args.inflation:g}; "
          f"{len(rows['all'])} keyframe poses; "
          f"{time.perf_counter() - t0:.0f} s\n")
    print("| block | dof | mean NEES | mean / dof (optimism) | inside 95 % bound | inflation for 95 % inside |")
    print("|---|---|---|---|---|---|")
    blocks = (("pose", "all", 6), ("rotation", "rot", 3), ("position", "pos", 3),
              ("pose, keyframes of the first window (gauge prior only)", "first", 6),
              ("pose, later keyframes (marginal prior)", "later", 6))
    for name, key, dof in blocks:
        if rows[key]:
            m, ratio, frac, f95 = summary(rows[key], dof)
            print(f"| {name} ({len(rows[key])}) | {dof} | {m:.2f} | {ratio:.2f} | {100 * frac:.0f} % | {f95:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
