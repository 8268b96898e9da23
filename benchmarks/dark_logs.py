"""Dark and flat logs (issue 31 item 1): does the odometry flag the frames whose pose the images do
not determine, and only those?

    python benchmarks/dark_logs.py [--log kitti|raw|synthetic] [--factors 1,0.2,0.1,0.05,0.03]
                                   [--max-frames N] [--max-relative-rms X] [--json OUT]

Every image of the log becomes ``round(f * I)`` (uint8, grey levels ``0 .. 255 f``): a sensor
exposed ``f`` times as long, quantised by its 8 bits. Each factor runs in window mode with the
defaults. Per factor: the frames whose relative step (to the previous frame, against the ground
truth, or the run at full exposure when the log has none) is off by more than 0.1 m ("bad"), the frames flagged as failed (re-initialised or lost)
or suspect, their overlap, the frames failed because "the images do not determine the pose"
(``TrackingConfig.max_relative_rms``), the report's ``trusted_fraction`` and the ATE (SE(3)-aligned). A
factor the run refuses ("only N points with a valid depth") is listed as refused.
``--max-relative-rms 1e9`` turns the check off (the odometry before it). Deterministic.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gtvo.config import OdometryConfig, as_config  # noqa: E402
from gtvo.frontend.tracking import TrackingConfig  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402
from gtvo.datasets.sequence import Sequence  # noqa: E402
from gtvo.datasets.synthetic import make_synthetic_sequence  # noqa: E402
from gtvo.errors import InputError  # noqa: E402
from gtvo.evaluation.metrics import ate  # noqa: E402
from gtvo.evaluation.trajectory import Trajectory  # noqa: E402
from gtvo.core.atomic import write_json  # noqa: E402
from gtvo.pipeline import process_sequence  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "data"
LOGS = {"kitti": "kitti_stereo_sample/KITTI_sequence_1", "raw": "kitti_raw_2011_09_26_drive_0001_stereo"}
BAD_STEP_M = 0.1


def darkened(seq: Sequence, factor: float) -> Sequence:
    """``seq`` with every image ``round(factor * I)`` as uint8 (left and right)."""
    def dim(load):
        return lambda i: np.clip(np.rint(np.asarray(load(i), dtype=np.float32) * factor), 0, 255).astype(np.uint8)
    return dataclasses.replace(seq, load_left=dim(seq.load_left), load_right=dim(seq.load_right))


def step_errors(poses: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Per frame k >= 1: the translation error (m) of the step from frame k-1 to k against the truth."""
    out = [np.linalg.norm((np.linalg.inv(poses[k - 1]) @ poses[k])[:3, 3] - (np.linalg.inv(gt[k - 1]) @ gt[k])[:3, 3])
           for k in range(1, len(poses))]
    return np.array(out)


def evaluate(seq: Sequence, factor: float, config: OdometryConfig, reference: np.ndarray) -> dict[str, Any]:
    """One factor: the flags against the frames whose step (against ``reference``'s poses) is bad."""
    dim = darkened(seq, factor) if factor != 1.0 else seq
    try:
        vo, traj, info = process_sequence(dim, config, warn=lambda m: None)
    except InputError as exc:
        return {"factor": factor, "refused": str(exc)}
    err = step_errors(traj.poses, reference)
    bad = {int(k) + 1 for k in np.flatnonzero(err > BAD_STEP_M)}
    failed = {e.index for e in vo.estimates if e.reinitialised or e.lost}
    flagged = failed | {e.index for e in vo.estimates if e.suspect}
    undetermined = set(info["undetermined_frames"])
    ate_m = ate(traj, Trajectory(traj.timestamps, reference, name="reference")).rmse
    return {"factor": factor, "frames": len(vo.estimates), "bad": sorted(bad), "flagged": sorted(flagged),
            "undetermined": sorted(undetermined), "bad_flagged": len(bad & flagged),
            "bad_unflagged": sorted(bad - flagged), "flagged_good": sorted(flagged - bad),
            "trusted_fraction": info["trusted_fraction"], "ate_m": ate_m,
            "median_step_error_m": float(np.median(err))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--log", choices=("kitti", "raw", "synthetic"), default="kitti")
    ap.add_argument("--factors", default="1,0.2,0.1,0.05,0.03")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--max-relative-rms", type=float, default=TrackingConfig().max_relative_rms)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    config = as_config({"tracking": {"max_relative_rms": args.max_relative_rms}})
    if args.log == "synthetic":
        seq = make_synthetic_sequence(n_frames=args.max_frames or 30)
    else:
        root = Path(os.environ.get("GTVO_SHARED_DATA", DATA))
        seq = open_sequence(root / LOGS[args.log], max_frames=args.max_frames)
    reference = seq.gt_poses
    if reference is None:  # no ground truth (the raw drive here): the run at full exposure
        reference = process_sequence(seq, config, warn=lambda m: None)[1].poses
        print("(no ground truth: errors against the run at full exposure)")
    rows = []
    print(f"{args.log}, {len(seq)} frames, tracking.max_relative_rms {args.max_relative_rms:g}; bad: step error > {BAD_STEP_M} m; flagged: failed or suspect")
    print("| factor | bad | flagged | bad and flagged | bad, not flagged | flagged, not bad | undetermined | trusted | ATE (m) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for f in (float(x) for x in args.factors.split(",")):
        r = evaluate(seq, f, config, reference)
        rows.append(r)
        if "refused" in r:
            print(f"| {f:g} | refused: {r['refused'].split(';')[0]} | | | | | | | |", flush=True)
            continue
        print(f"| {f:g} | {len(r['bad'])} | {len(r['flagged'])} | {r['bad_flagged']} | {len(r['bad_unflagged'])} "
              f"{r['bad_unflagged'][:8]} | {len(r['flagged_good'])} {r['flagged_good'][:8]} | {len(r['undetermined'])} "
              f"| {r['trusted_fraction']:.0%} | {r['ate_m']:.3f} |", flush=True)
    if args.json is not None:
        write_json(args.json, {"log": args.log, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
