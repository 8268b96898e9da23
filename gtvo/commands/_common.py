"""Argument helpers shared by subcommands."""

from __future__ import annotations

import argparse
from typing import Any

from gtvo.errors import InputError


def parse_floats(text: str, n: int, what: str) -> tuple[float, ...]:
    """Parse ``"a,b,c"`` into ``n`` finite floats, or raise :class:`InputError` naming ``what``."""
    parts = [p.strip() for p in text.split(",")]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        raise InputError(f"{what} must be {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n or not all(v == v and abs(v) != float("inf") for v in vals):
        raise InputError(f"{what} must be {n} comma-separated finite numbers, got {text!r}")
    return vals


def add_odometry_options(p: argparse.ArgumentParser) -> None:
    """Options of the odometry shared by ``run`` and ``demo``."""
    p.add_argument("--mode", choices=("window", "track"), default="window",
                   help="window (default): every new keyframe joins a sliding window of 7 keyframes whose poses, "
                        "brightness and inverse depths are optimised jointly; track: each frame is only tracked "
                        "against the latest keyframe (faster, less accurate)")
    p.add_argument("--window-backend", choices=("lm", "fixed-lag"), default=None,
                   help="lm (default): each window solved by --solver's Levenberg-Marquardt with a hand-made "
                        "marginalisation prior; fixed-lag: gtsam.IncrementalFixedLagSmoother (iSAM2) keeps the "
                        "window and marginalises the keyframes that leave it")
    p.add_argument("--solver", choices=("handrolled", "gtsam"), default="handrolled",
                   help="solver of the frame tracker and of the window (default: handrolled)")
    p.add_argument("--points", type=int, default=300, metavar="N", help="points per keyframe (default 300)")
    p.add_argument("--motion-model", choices=("constant-velocity", "kalman"), default="constant-velocity",
                   help="initial guess of each frame's pose (default: constant-velocity)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def odometry_config(args: Any):
    """An :class:`OdometryConfig` from parsed options."""
    from gtvo.config import MIN_POINTS_PER_KEYFRAME, OdometryConfig  # noqa: PLC0415
    from gtvo.window import WindowConfig  # noqa: PLC0415

    if args.points < MIN_POINTS_PER_KEYFRAME:
        raise InputError(f"--points must be >= {MIN_POINTS_PER_KEYFRAME}, got {args.points}")
    if args.window_backend is not None and args.mode != "window":
        raise InputError(f"--window-backend {args.window_backend} needs --mode window (got --mode {args.mode})")
    backend = "fixed_lag" if args.window_backend == "fixed-lag" else "lm"
    return OdometryConfig(solver=args.solver, points_per_keyframe=args.points, motion_model=args.motion_model,
                          mode=args.mode, window_solver=args.solver, window=WindowConfig(backend=backend))


#: The report's headline figures, in the order the console summary prints them.
SUMMARY_KEYS = ("frames", "keyframes", "seconds", "frames_per_second", "tracking_failures", "flow_recoveries",
                "lost_frames", "window_optimisations", "window_seconds_mean", "ate_rmse_m", "rpe_trans_rmse_m",
                "ate_skipped", "drift_percent", "loops_detected", "loops_accepted", "loop_closed_ate_rmse_m",
                "loop_closed_drift_percent", "map_points_written", "map_points_left_out", "map_points_skipped",
                "unpaired_messages")


def describe_solvers(report: dict[str, Any]) -> str:
    """What ran, from a run's report: mode, the tracker's solver and the window's back end and solver."""
    text = f"{report['mode']}, tracker {report['tracker_solver']}"
    if report.get("window_backend") is not None:
        text += f", window {report['window_backend']} back end with {report['window_solver']}"
    if report.get("loop_closure_solver") is not None:
        text += f", loop closure {report['loop_closure_solver']}"
    return text


def print_report(report: dict[str, Any]) -> None:
    """Print the headline figures of a run's report, one per line, values in one column."""
    shown = [k for k in SUMMARY_KEYS if report.get(k) is not None]
    width = max((len(k) for k in shown), default=0) + 1
    for k in shown:
        v = report[k]
        print(f"  {k:<{width}} {v:.4g}" if isinstance(v, float) else f"  {k:<{width}} {v}")
    print(f"  outputs in {report['out']}")
