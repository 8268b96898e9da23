"""Loop closure: open-loop vs loop-closed ATE on synthetic loops and on clips without a loop.

For each sequence the VO runs once (``gtvo run``'s defaults: window mode), then
:func:`gtvo.loops.closing.close_loops_of_run` gets exactly what ``gtvo run --loop-closure`` gives it
(the tracker's odometry covariances, the VO's keyframe points, ``refine_frames``). Printed per
sequence: keyframes, loops verified / measured by direct alignment / kept by GNC, the open-loop
ATE (``gtvo run``), the ATE with the frames refined against the open-loop keyframes (what the frame
refinement alone does), the loop-closed ATE (``--loop-closure``: loops closed, then frames refined)
and its ratios to both, and, as a bound, the ATE with every keyframe put at its ground-truth pose
and the other frames refined against them (the best any keyframe pose graph can do here). The
"s" column is the run, loop closing and frame refinement of ``--loop-closure`` (not the extra
refinements of the two reference columns).

Synthetic loops (``gtvo synthetic --motion loop``): several seeds, sizes, frame counts and image
noise levels, rendered in memory. Sequences without a loop: synthetic forward and turn runs, the KITTI snippet
(``../shared/data/kitti_stereo_sample/KITTI_sequence_1``, a straight 60 m drive) and TUM fr3/teddy's
first 20 frames (``../shared/data/rgbd_dataset_freiburg3_teddy_first20``), when present.

Usage: python benchmarks/loop_closure_synthetic.py [--quick]   (--quick: the two smallest loops only)
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from gtvo.datasets import open_sequence
from gtvo.datasets.sequence import Sequence
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.evaluation.trajectory import Trajectory
from gtvo.evaluation.accuracy import evaluate, ground_truth
from gtvo.loops.closing import close_loops_of_run, odometry_covariances, odometry_informations, relocate_frames
from gtvo.loops.frame_refinement import refine_frames
from gtvo.pipeline import TRACKED_OUTCOMES, process_sequence

def _shared_data() -> Path:
    """``shared/data`` next to the checkout (or next to any folder above it: worktrees sit deeper)."""
    for parent in Path(__file__).resolve().parents[1:]:
        if (parent / "shared" / "data").is_dir():
            return parent / "shared" / "data"
    return Path(__file__).resolve().parents[1].parent / "shared" / "data"


DATA = _shared_data()
KITTI = DATA / "kitti_stereo_sample" / "KITTI_sequence_1"
TUM = DATA / "rgbd_dataset_freiburg3_teddy_first20"

#: (seed, frames, width, height, image noise sigma in grey levels)
LOOPS = [
    (0, 100, 320, 240, 0.0),   # short: little drift, the frames' own tracking error dominates the ATE
    (1, 300, 320, 240, 0.0),
    (2, 300, 320, 240, 2.0),
    (3, 250, 320, 240, 1.0),
    (4, 250, 320, 240, 3.0),
    (5, 240, 640, 480, 0.0),
    (6, 200, 320, 240, 0.0),
]
#: synthetic runs without a loop: (motion, seed, frames)
NO_LOOPS = [("forward", 7, 120), ("turn", 7, 120)]


def measure(seq: Sequence) -> dict[str, float | int]:
    """Run the VO and the loop closing on ``seq``; return the row of the table."""
    t0 = time.perf_counter()
    vo, traj, _ = process_sequence(seq)
    estimates = vo.estimates
    kfs = [p for p, e in enumerate(estimates) if e.is_keyframe]
    indices = [e.index for e in estimates]
    covariances = odometry_covariances(estimates, kfs)
    points = {kf.index: kf.points for kf in vo.keyframes}
    refine = [e.outcome in TRACKED_OUTCOMES for e in estimates]
    res = close_loops_of_run(seq, traj, indices, kfs, odometry_covariances=covariances, keyframe_points=points,
                             tracking_config=vo.config.tracking, refine_frames=True, refine=refine)
    seconds = time.perf_counter() - t0

    def ate(poses: NDArray[np.float64]) -> float:
        return evaluate(*ground_truth(seq, Trajectory(traj.timestamps, poses)))["ate_rmse_m"]

    def frames_refined(keyframe_poses: NDArray[np.float64]) -> NDArray[np.float64]:
        """Every frame moved with its keyframe placed at ``keyframe_poses``, then refined against them."""
        kf_points = [points.get(indices[k]) for k in kfs]
        edge_cov = np.linalg.inv(odometry_informations(len(kfs), covariances))
        return refine_frames(seq.pinhole, lambda p: seq.frame(indices[p]).left,
                             relocate_frames(traj.poses, kfs, keyframe_poses), kfs, kf_points, edge_cov,
                             refine=refine, config=vo.config.tracking).poses

    gt = seq.gt_poses[indices]
    return {"keyframes": len(kfs), "verified": len(res.candidates) + len(res.unrefined),
            "measured": len(res.candidates), "kept": int(sum(res.accepted)), "open": ate(traj.poses),
            "frames": ate(frames_refined(traj.poses[kfs])), "closed": ate(res.trajectory.poses),
            "bound": ate(frames_refined(gt[kfs])), "seconds": seconds}


def row(name: str, m: dict[str, float | int]) -> str:
    """One Markdown table row."""
    return (f"| {name} | {m['keyframes']} | {m['verified']} / {m['measured']} / {m['kept']} | "
            f"{1000 * m['open']:.1f} | {1000 * m['frames']:.1f} ({m['frames'] / m['open']:.2f}) | "
            f"{1000 * m['closed']:.1f} | **{m['closed'] / m['open']:.2f}** | {m['closed'] / m['frames']:.2f} | "
            f"{m['bound'] / m['open']:.2f} | {m['seconds']:.0f} |")


def main(argv: list[str]) -> None:
    quick = "--quick" in argv
    print("| sequence | keyframes | loops verified / measured / kept | open ATE [mm] | frames refined, no loop [mm] "
          "| closed ATE [mm] | ratio closed / open | closed / frames refined | bound ratio | s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for seed, frames, w, h, noise in (LOOPS[:2] if quick else LOOPS):
        seq = make_synthetic_sequence(n_frames=frames, width=w, height=h, noise_sigma=noise, seed=seed, motion="loop")
        print(row(f"loop seed {seed}, {frames} frames, {w}x{h}, noise {noise:g}", measure(seq)), flush=True)
    if quick:
        return
    for motion, seed, frames in NO_LOOPS:
        seq = make_synthetic_sequence(n_frames=frames, seed=seed, motion=motion)
        print(row(f"{motion} seed {seed}, {frames} frames, 320x240 (no loop)", measure(seq)), flush=True)
    for name, path in (("KITTI_sequence_1 (no loop)", KITTI), ("TUM fr3/teddy first 20 (no loop)", TUM)):
        if path.exists():
            print(row(name, measure(open_sequence(path))), flush=True)
        else:
            print(f"| {name} | missing: {path} |")


if __name__ == "__main__":
    main(sys.argv[1:])
