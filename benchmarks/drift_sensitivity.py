"""How much of a drift figure is the method, and how much is chance? Parameter sweeps on one log.

    python benchmarks/drift_sensitivity.py [--sequence DIR] [--max-frames N] [--json OUT]

The issue's drift (final position error after aligning the *first* pose, % of the path) is one
number per run: on a 51-frame, 60 m snippet it is the sum of a handful of rotation errors levered
over the remaining path, and errors of opposite sign cancel. This script runs, on the same
preloaded frames,

* gtvo (window mode, hand-rolled tracker and window solver) over a grid of its two main sizes:
  points per keyframe (200, 300, 500) x window size (5, 7, 9);
* the ORB + SGBM + solvePnPRansac peer (``benchmarks/peers.py``) over a grid of its three main
  settings: ORB features (1000, 2000, 3000, 5000) x Lowe ratio (0.7, 0.8) x RANSAC threshold
  (1, 1.5, 3 px);

and prints for every setting the ATE (SE(3)-aligned), the drift from frame 0, and the KITTI
devkit's segment errors over 10-40 m segments from every frame (``benchmarks/vo_bench.py``'s
``score``); then per method the range and median of each column, and for the two default
settings the drift anchored at every frame 0..N/2 (the first pose of the alignment moved along
the log) with the number of anchors where each is lower.

Nothing here is tuned: the grids bracket each method's defaults. Figures and their reading:
docs/benchmarks.md, "How much of the drift figure is chance?".
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.peers import OrbPnPPeer, run_peer  # noqa: E402
from benchmarks.vo_bench import KITTI_SEQUENCE_1, fmt, load_frames, markdown_table, run_gtvo, score  # noqa: E402
from gtvo.core.atomic import write_json  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402
from gtvo.evaluation.metrics import drift_percent  # noqa: E402
from gtvo.config import FrontendConfig, OdometryConfig, SolverConfig  # noqa: E402
from gtvo.datasets.sequence import Sequence  # noqa: E402
from gtvo.evaluation.trajectory import Trajectory  # noqa: E402
from gtvo.window import WindowConfig  # noqa: E402

GTVO_GRID = {"points_per_keyframe": (200, 300, 500), "window_size": (5, 7, 9)}
ORB_GRID = {"n_features": (1000, 2000, 3000, 5000), "ratio": (0.7, 0.8), "reprojection_error": (1.0, 1.5, 3.0)}
COLUMNS = (("ate_m", "ATE (m)", ".3f"), ("drift_pct", "drift % (frame 0)", ".2f"),
           ("seg_t_pct", "seg t %", ".2f"), ("seg_r_deg_per_100m", "seg r (deg/100 m)", ".2f"))


def anchored_drifts(est: Trajectory, ref: Trajectory, last_anchor: int) -> np.ndarray:
    """The drift (% of the remaining path) with the alignment anchored at frame 0..last_anchor."""
    return np.array([drift_percent(Trajectory(ref.timestamps[a:], est.poses[a:], "est"),
                                   Trajectory(ref.timestamps[a:], ref.poses[a:], "ref"))
                     for a in range(last_anchor + 1)])


def sweep(seq: Sequence, progress: bool) -> dict[str, Any]:
    """Every setting of both grids on the same frames; rows and the default runs' trajectories."""
    frames = load_frames(seq, progress)
    rows: list[dict[str, Any]] = []
    defaults: dict[str, Trajectory] = {}
    base = OdometryConfig(solver=SolverConfig(window="handrolled"))
    for ppk, size in itertools.product(*GTVO_GRID.values()):
        label = f"gtvo points/kf {ppk}, window {size}"
        print(f"  {label} ...", file=sys.stderr, flush=True)
        config = OdometryConfig(solver=SolverConfig(window="handrolled"), frontend=FrontendConfig(points_per_keyframe=ppk),
                                window=WindowConfig(size=size))
        run = run_gtvo(seq.camera, frames, config)
        rows.append({"method": "gtvo", "setting": label, "default": (ppk, size) == (base.frontend.points_per_keyframe,
                                                                                   base.window.size),
                     **score(run["trajectory"], seq)})
        if rows[-1]["default"]:
            defaults["gtvo"] = run["trajectory"]
    default_orb = OrbPnPPeer(seq.camera)
    for nf, ratio, rep in itertools.product(*ORB_GRID.values()):
        label = f"ORB features {nf}, ratio {ratio:g}, RANSAC {rep:g} px"
        print(f"  {label} ...", file=sys.stderr, flush=True)
        peer = OrbPnPPeer(seq.camera, n_features=nf, ratio=ratio, reprojection_error=rep)
        run = run_peer(peer, frames, label)
        is_default = ((peer.n_features, peer.ratio, peer.reprojection_error)
                      == (default_orb.n_features, default_orb.ratio, default_orb.reprojection_error))
        rows.append({"method": "orb", "setting": label, "default": is_default, **score(run.trajectory, seq)})
        if is_default:
            defaults["orb"] = run.trajectory
    return {"rows": rows, "defaults": defaults}


def summary(rows: list[dict[str, Any]]) -> str:
    """Per method: min / median / max of every column over its grid."""
    out = []
    for method in ("gtvo", "orb"):
        mine = [r for r in rows if r["method"] == method]
        cells = [method, str(len(mine))]
        for key, _, spec in COLUMNS:
            v = np.array([r[key] for r in mine if r[key] is not None], dtype=float)
            cells.append(f"{fmt(v.min(), spec)} / {fmt(float(np.median(v)), spec)} / {fmt(v.max(), spec)}"
                         if v.size else "-")
        out.append(cells)
    header = ["method", "settings"] + [f"{title}: min / median / max" for _, title, _ in COLUMNS]
    return markdown_table(header, out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", type=Path, default=KITTI_SEQUENCE_1, metavar="DIR")
    ap.add_argument("--max-frames", type=int, default=None, metavar="N")
    ap.add_argument("--json", type=Path, default=None, metavar="OUT", help="also write all figures as JSON")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)

    seq = open_sequence(args.sequence, max_frames=args.max_frames)
    if seq.gt_poses is None:
        print(f"error: {args.sequence} has no ground truth", file=sys.stderr)
        return 2
    result = sweep(seq, not args.no_progress)
    rows = result["rows"]
    print(f"### {seq.name} ({len(seq)} frames)\n")
    table = [[r["setting"] + (" (default)" if r["default"] else "")] + [fmt(r[k], s) for k, _, s in COLUMNS]
             for r in rows]
    print(markdown_table(["setting"] + [t for _, t, _ in COLUMNS], table))
    print("\nOver each grid:\n")
    print(summary(rows))

    ref = Trajectory(seq.timestamps, seq.gt_poses, "gt")
    last = len(seq) // 2
    anchored = {m: anchored_drifts(t, ref, last) for m, t in result["defaults"].items()}
    print(f"\nDefault settings, drift with the alignment anchored at frame a = 0..{last} (% of the path after a):\n")
    print(markdown_table(["a"] + list(anchored), [[str(a)] + [f"{anchored[m][a]:.2f}" for m in anchored]
                                                  for a in range(last + 1)]))
    if {"gtvo", "orb"} <= anchored.keys():
        lower = int(np.sum(anchored["gtvo"] < anchored["orb"]))
        print(f"\ngtvo's drift is lower at {lower} of {last + 1} anchors; mean over anchors: "
              f"gtvo {anchored['gtvo'].mean():.2f} %, ORB {anchored['orb'].mean():.2f} %")
    if args.json:
        write_json(args.json, {"sequence": str(args.sequence), "frames": len(seq), "rows": rows,
                               "anchored_drift_pct": {m: v.tolist() for m, v in anchored.items()}})
    return 0


if __name__ == "__main__":
    sys.exit(main())
