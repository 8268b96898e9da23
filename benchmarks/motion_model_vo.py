"""Tracker initial guess: constant velocity vs the constant-acceleration Kalman filter, in gtvo's
VO on real KITTI frames, one run (issue 7, item 3).

    python benchmarks/motion_model_vo.py [--sequence DIR] [--max-frames N] [--solvers handrolled,gtsam]
                                         [--repeats R] [--json OUT]

For each solver, gtvo runs in ``mode="track"`` (the tracker alone, no window) with
``OdometryConfig(motion_model="constant-velocity")`` and with
``motion_model="kalman"`` on the same preloaded frames (interleaved, ``--repeats`` times; the
figures except time are deterministic, the time is the median). Rows: mean tracking iterations
per tracked frame (the tracker's LM iterations summed over pyramid levels, as
``TrackingResult.iterations`` counts them), tracking failures, keyframes, ATE RMSE (SE(3)),
drift %, RPE over 1 frame, ms/frame, and the initial guess's own error: the RMS, over frames 2..N-1,
of the predicted motion (previous estimate -> predicted pose) against the ground-truth motion,
translation (m) and rotation (deg), and the same from frame 6 on (after the filter's start-up:
it starts at rest, the car at 12 m/s).

Caveat: on a tracking failure gtvo keeps the prediction as the frame's pose, so the motion model
also moves ATE and drift through the failed frames, not only through the tracker's start.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.vo_bench import (KITTI_SEQUENCE_1, fmt, gtvo_config, load_frames, markdown_table,  # noqa: E402
                                 run_gtvo, score)
from gtvo.core.lie import invert_poses, rotation_angle  # noqa: E402
from gtvo.core.atomic import write_json  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402

MODELS = ("constant-velocity", "kalman")
#: The guess error is also given from this frame on: the filter starts at rest (zero rate) and
#: needs a few frames to learn the speed, while constant velocity knows it from frame 2.
LATE = 6


def guess_errors(predictions: dict[int, np.ndarray], est: np.ndarray, gt: np.ndarray | None,
                 first: int = 2) -> tuple[float | None, float | None]:
    """RMS translation (m) and rotation (deg) error of the predicted frame-to-frame motion vs GT,
    over frames ``first`` .. N-1 (frame 1 has no motion model yet: both guess "no motion")."""
    ks = [k for k in sorted(predictions) if k >= first]
    if gt is None or not ks:
        return None, None
    ks = [k for k in ks if np.isfinite(gt[k, 0, 0]) and np.isfinite(gt[k - 1, 0, 0])]
    if not ks:
        return None, None
    k = np.array(ks)
    P = np.stack([predictions[i] for i in ks])
    E = invert_poses(invert_poses(gt[k - 1]) @ gt[k]) @ (invert_poses(est[k - 1]) @ P)
    t = np.linalg.norm(E[:, :3, 3], axis=1)
    r = np.degrees(rotation_angle(E[:, :3, :3]))
    return float(np.sqrt(np.mean(t * t))), float(np.sqrt(np.mean(r * r)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", type=Path, default=KITTI_SEQUENCE_1, metavar="DIR")
    ap.add_argument("--max-frames", type=int, default=None, metavar="N")
    ap.add_argument("--solvers", default="handrolled", help="gtvo solvers (comma-separated)")
    ap.add_argument("--repeats", type=int, default=1, help="runs per row (time: median)")
    ap.add_argument("--json", type=Path, default=None, metavar="OUT")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    seq = open_sequence(args.sequence, max_frames=args.max_frames)
    frames = load_frames(seq, not args.no_progress)
    rows = []
    for solver in [s.strip() for s in args.solvers.split(",") if s.strip()]:
        runs: dict[str, list[dict]] = {m: [] for m in MODELS}
        for _ in range(max(1, args.repeats)):
            for model in MODELS:
                print(f"  running {solver}, {model} ...", file=sys.stderr, flush=True)
                g = run_gtvo(seq.camera, frames, gtvo_config(solver, motion_model=model), record_predictions=True)
                g.pop("vo")
                traj = g.pop("trajectory")
                preds = g.pop("predictions")
                g["guess_t_m"], g["guess_r_deg"] = guess_errors(preds, traj.poses, seq.gt_poses)
                g["guess_t_m_late"], g["guess_r_deg_late"] = guess_errors(preds, traj.poses, seq.gt_poses, LATE)
                g.update(score(traj, seq))
                runs[model].append(g)
        for model in MODELS:
            g = runs[model][0]
            secs = float(np.median([r["seconds"] for r in runs[model]]))
            rows.append({"solver": solver, "motion_model": model, "frames": len(frames),
                         "tracking_iterations_mean": g["tracking_iterations_mean"], "failures": g["failures"],
                         "keyframes": g["keyframes"], "guess_t_m": g["guess_t_m"], "guess_r_deg": g["guess_r_deg"],
                         "guess_t_m_late": g["guess_t_m_late"], "guess_r_deg_late": g["guess_r_deg_late"],
                         "ate_m": g["ate_m"], "drift_pct": g["drift_pct"],
                         "rpe_t_m": g["rpe_t_m"], "rpe_r_deg": g["rpe_r_deg"],
                         "ms_per_frame": 1000.0 * secs / len(frames),
                         "deterministic": all(r["ate_m"] == g["ate_m"] for r in runs[model])})
    header = ["solver", "initial guess", "guess err t (m)", "guess err r (deg)", f"guess err t, r from frame {LATE}",
              "tracking iterations (mean)",
              "failures", "keyframes", "ATE RMSE (m)",
              "drift %", "RPE t (m)", "RPE r (deg)", "ms/frame"]
    print(f"\n### {seq.name} ({len(frames)} frames)\n")
    print(markdown_table(header, [[r["solver"], r["motion_model"], fmt(r["guess_t_m"], ".3f"),
                                   fmt(r["guess_r_deg"], ".3f"),
                                   f"{fmt(r['guess_t_m_late'], '.3f')} m, {fmt(r['guess_r_deg_late'], '.3f')} deg",
                                   fmt(r["tracking_iterations_mean"], ".2f"),
                                   str(r["failures"]), str(r["keyframes"]), fmt(r["ate_m"], ".3f"),
                                   fmt(r["drift_pct"], ".2f"), fmt(r["rpe_t_m"], ".3f"), fmt(r["rpe_r_deg"], ".3f"),
                                   fmt(r["ms_per_frame"], ".0f")] for r in rows]))
    if args.json is not None:
        write_json(args.json, {"command": " ".join(sys.argv), "sequence": str(args.sequence), "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
