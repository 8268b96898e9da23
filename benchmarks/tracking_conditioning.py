"""The tracker's conditioning check (``TrackingConfig.max_rotation_sigma_deg``): what it catches on
a synthetic turn, and how far every real log stays from it.

    python benchmarks/tracking_conditioning.py [--frames N] [--solver handrolled|gtsam]
                                               [--sequence DIR ...] [--json OUT]

1. The synthetic ``"turn"`` sequence (``make_synthetic_sequence(N, motion="turn", step_m=0.3,
   noise_sigma=1)``: a car-like right turn at 3 deg per frame that ends facing the room's close,
   low-texture side wall), window mode, with the check (default bound, 1 deg) and without it
   (bound infinite): ATE (SE(3)), the largest and the final rotation error against the ground
   truth, failures, lost frames.
2. Every tracked frame of the real logs (default: KITTI_sequence_1 at every frame and every 3rd,
   the static EuRoC clip, TUM teddy), window mode, CLI defaults: the tracked frames' rotation
   sigma (median, max), failures, and how many tracking results the check turned into failures.

Rows are deterministic (no timing).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.vo_bench import KITTI_SEQUENCE_1, SHARED_DATA, fmt, gtvo_config, markdown_table  # noqa: E402
from gtvo.core.atomic import write_json  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402
from gtvo.evaluation.metrics import ate  # noqa: E402
from gtvo.config import OdometryConfig
from gtvo.odometry import VisualOdometry  # noqa: E402
from gtvo.datasets.sequence import Sequence  # noqa: E402
from gtvo.datasets.synthetic import make_synthetic_sequence  # noqa: E402
from gtvo.evaluation.trajectory import Trajectory  # noqa: E402
from gtvo.core.lie import rotation_angle  # noqa: E402
from gtvo.frontend.tracking import TrackingConfig  # noqa: E402

REAL_LOGS: tuple[tuple[Path, int], ...] = (
    (KITTI_SEQUENCE_1, 1), (KITTI_SEQUENCE_1, 3),
    (SHARED_DATA / "euroc_v101_static_stereo", 1), (SHARED_DATA / "rgbd_dataset_freiburg3_teddy_first20", 1))
CHECK = "poorly constrained"


def run(seq: Sequence, config: OdometryConfig, step: int = 1) -> VisualOdometry:
    vo = VisualOdometry(seq.camera, config)
    for i in range(0, len(seq), step):
        vo.process(seq.frame(i))
    vo.finish()
    return vo


def rotation_errors(est: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Rotation error (deg) of each estimated pose against the ground truth (frame 0 at identity in both)."""
    return np.degrees(rotation_angle(np.swapaxes(est[:, :3, :3], 1, 2) @ gt[:, :3, :3]))


def tracked_sigmas(vo: VisualOdometry) -> list[float]:
    return [e.tracking.rotation_sigma_deg for e in vo.estimates if e.tracking is not None and e.tracking.success]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40, help="frames of the synthetic turn")
    ap.add_argument("--solver", default="handrolled", choices=("handrolled", "gtsam"))
    ap.add_argument("--sequence", type=Path, action="append", default=None, metavar="DIR",
                    help="real logs (repeatable; default: the four of the docstring)")
    ap.add_argument("--json", type=Path, default=None, metavar="OUT")
    args = ap.parse_args(argv)

    seq = make_synthetic_sequence(args.frames, motion="turn", step_m=0.3, noise_sigma=1.0)
    gt = seq.gt_poses
    assert gt is not None
    turn_rows = []
    for label, bound in (("with the check (1 deg)", TrackingConfig().max_rotation_sigma_deg),
                         ("without it", float("inf"))):
        print(f"  synthetic turn, {label} ...", file=sys.stderr, flush=True)
        cfg = gtvo_config(args.solver, "window", tracking=TrackingConfig(max_rotation_sigma_deg=bound))
        vo = run(seq, cfg)
        traj = vo.trajectory("gtvo")
        rerr = rotation_errors(traj.poses, gt)
        sig = tracked_sigmas(vo)
        turn_rows.append({"run": label, "ate_m": ate(traj, Trajectory(seq.timestamps, gt, "gt"), "se3").rmse,
                          "max_rot_err_deg": float(rerr.max()), "final_rot_err_deg": float(rerr[-1]),
                          "failures": vo.failures, "lost_frames": vo.lost_frames,
                          "sigma_max_deg": max(sig) if sig else None})
    print(f"\n### Synthetic turn ({len(seq)} frames, 3 deg/frame, 0.3 m/frame, {args.solver})\n")
    print(markdown_table(["run", "ATE (m)", "max rot err (deg)", "final rot err (deg)", "failures", "lost frames",
                          "largest accepted rotation sigma (deg)"],
                         [[r["run"], fmt(r["ate_m"], ".3f"), fmt(r["max_rot_err_deg"], ".2f"),
                           fmt(r["final_rot_err_deg"], ".2f"), str(r["failures"]), str(r["lost_frames"]),
                           fmt(r["sigma_max_deg"], ".3f")] for r in turn_rows]))

    logs = [(p, 1) for p in args.sequence] if args.sequence else list(REAL_LOGS)
    real_rows = []
    for path, step in logs:
        print(f"  {path.name}, every {step} frame(s) ...", file=sys.stderr, flush=True)
        s = open_sequence(path)
        vo = run(s, gtvo_config(args.solver, "window"), step)
        sig = tracked_sigmas(vo)
        caught = sum(1 for e in vo.estimates if e.tracking is not None and CHECK in e.tracking.reason)
        real_rows.append({"sequence": s.name, "frame_step": step, "frames": len(vo.estimates),
                          "tracked": len(sig), "sigma_median_deg": float(np.median(sig)) if sig else None,
                          "sigma_max_deg": max(sig) if sig else None, "failures": vo.failures,
                          "failed_by_check": caught})
    print(f"\n### Real logs: rotation sigma of the tracked frames ({args.solver}, window mode)\n")
    print(markdown_table(["sequence", "frame step", "frames", "tracked", "sigma median (deg)", "sigma max (deg)",
                          "failures", "failed by the check"],
                         [[r["sequence"], str(r["frame_step"]), str(r["frames"]), str(r["tracked"]),
                           fmt(r["sigma_median_deg"], ".4f"), fmt(r["sigma_max_deg"], ".4f"), str(r["failures"]),
                           str(r["failed_by_check"])] for r in real_rows]))
    if args.json is not None:
        write_json(args.json, {"command": " ".join(sys.argv), "turn": turn_rows, "real": real_rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
