"""When the window is optimised (``WindowConfig.optimize_every``): accuracy and time on KITTI at
several frame steps, every start phase of each step (docs/window.md, "When the window is optimised").

    python benchmarks/window_schedule.py [--sequence DIR] [--every 1,2,3] [--steps 1,2,3]

Each cell: window ATE RMSE (m, SE(3)-aligned), window optimisations, CPU ms per frame (process
time of the run, frames preloaded). A frame step K with phase P plays frames P, P + K, P + 2K, ...
(the same road at 1/K of the frame rate; every phase is its own run).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.vo_bench import KITTI_SEQUENCE_1, load_frames, run_gtvo  # noqa: E402
from gtvo.config import OdometryConfig  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402
from gtvo.evaluation.metrics import ate  # noqa: E402
from gtvo.evaluation.trajectory import Trajectory  # noqa: E402
from gtvo.window import WindowConfig  # noqa: E402


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip()]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", type=Path, default=KITTI_SEQUENCE_1)
    ap.add_argument("--every", type=_ints, default=[1, 2, 3], help="optimize_every values (default 1,2,3)")
    ap.add_argument("--steps", type=_ints, default=[1, 2, 3], help="frame steps (default 1,2,3)")
    args = ap.parse_args(argv)
    seq = open_sequence(args.sequence)
    if not seq.has_ground_truth:
        raise SystemExit(f"{args.sequence}: no ground truth to score against")
    frames = load_frames(seq, False)
    print(f"{seq.name}: {len(frames)} frames; cells: ATE (m) / optimisations / CPU ms per frame\n")
    print("| step, phase | " + " | ".join(f"n = {n}" for n in args.every) + " |")
    print("|---|" + "---|" * len(args.every))
    for step in args.steps:
        for phase in range(step):
            idx = list(range(phase, len(frames), step))
            run_frames = [dataclasses.replace(frames[i], index=j) for j, i in enumerate(idx)]
            gt = Trajectory(np.asarray(seq.timestamps)[idx], np.asarray(seq.gt_poses)[idx], name="gt")
            cells = []
            for n in args.every:
                c0 = time.process_time()
                r = run_gtvo(seq.camera, run_frames, OdometryConfig(window=WindowConfig(optimize_every=n)))
                cpu = time.process_time() - c0
                est = Trajectory(gt.timestamps, r["trajectory"].poses, name="est")
                err = ate(est, gt, "se3").translation.rmse
                fail = f", {r['failures']} failed" if r["failures"] else ""
                cells.append(f"{err:.4f} / {len(r['vo'].window_results)} / {1000 * cpu / len(idx):.0f}{fail}")
            print(f"| {step}, {phase} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
