"""How the number of points per keyframe and the window's LM iterations trade accuracy for speed.

Runs gtvo on the same preloaded frames (default: KITTI_sequence_1) once per setting, one after
the other, and prints ATE RMSE (SE(3)-aligned), end-point drift (% of the GT path), 1-frame RPE,
frames per second, and ms per frame as a multiple of one OpenCV StereoSGBM of frame 0 measured
in the same run (the machine is shared: the ratio is what compares runs).

    python benchmarks/point_density.py [--sequence DIR] [--points 300,500,1000,2000]
        [--modes track,window] [--iterations 3,4,6]

``--iterations`` sweeps the window's ``max_iterations`` at the first ``--points`` value.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
if str(REPO_ROOT) not in sys.path:  # run as `python benchmarks/<script>.py`
    sys.path.insert(0, str(REPO_ROOT))

from benchmarks.vo_bench import (KITTI_SEQUENCE_1, fmt, load_frames, markdown_table, reference_ms,  # noqa: E402
                                 run_gtvo, score)
from gtvo.config import FrontendConfig, OdometryConfig  # noqa: E402
from gtvo import open_sequence  # noqa: E402
from gtvo.window import WindowConfig  # noqa: E402


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip()]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequence", type=Path, default=KITTI_SEQUENCE_1, metavar="DIR")
    ap.add_argument("--points", default="300,500,1000,2000", help="points per keyframe (comma-separated)")
    ap.add_argument("--modes", default="track,window", help="gtvo modes (comma-separated)")
    ap.add_argument("--iterations", default="3,4,6", help="window max_iterations to sweep ('' for none)")
    args = ap.parse_args(argv)
    seq = open_sequence(args.sequence)
    frames = load_frames(seq)
    points = _ints(args.points)
    settings = [(mode, n, WindowConfig().max_iterations) for mode in args.modes.split(",") for n in points]
    if "window" in args.modes.split(","):
        settings += [("window", points[0], it) for it in _ints(args.iterations) if it != WindowConfig().max_iterations]
    ref_before = reference_ms(frames)
    rows = []
    for mode, n, it in settings:
        cfg = OdometryConfig(mode=mode, frontend=FrontendConfig(points_per_keyframe=n),
                             window=WindowConfig(max_iterations=it))
        r = run_gtvo(seq.camera, frames, cfg)
        s = score(r["trajectory"], seq)
        ms = 1000.0 * r["seconds"] / len(frames)
        rows.append([mode, str(n), str(it) if mode == "window" else "-", fmt(s["ate_m"], ".3f"),
                     fmt(s["drift_pct"], ".2f"), fmt(s["rpe_t_m"], ".4f"), f"{ms:.0f}", f"{len(frames) / r['seconds']:.2f}",
                     str(r["keyframes"]), str(r["failures"])])
        print(" | ".join(rows[-1]), file=sys.stderr)
    ref_after = reference_ms(frames)
    ref = 0.5 * (ref_before + ref_after)
    for row in rows:
        row.insert(7, f"{float(row[6]) / ref:.2f}")
    print(f"{seq.name}: {len(frames)} frames; reference (one StereoSGBM of frame 0) {ref:.0f} ms "
          f"(before / after: {ref_before:.0f} / {ref_after:.0f} ms)\n")
    print(markdown_table(["mode", "points/kf", "window iterations", "ATE RMSE (m)", "drift %", "RPE t (m)",
                          "ms/frame", "x ref", "frames/s", "keyframes", "failures"], rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
