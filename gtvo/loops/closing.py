"""Loop closing after a VO run: place recognition over the keyframes, a robust keyframe pose graph.

1. Every keyframe of the run goes into a :class:`gtvo.loops.LoopDetector` (ORB bag of words,
   verified by PnP RANSAC on its stereo or RGB-D points) and is queried against the earlier ones.
2. The keyframe poses become a pose graph: consecutive keyframes are joined by their VO relative
   pose (odometry edges), every verified loop by its measured relative pose
   (``BetweenFactorPose3``), and :func:`gtvo.loops.closure_graph.close_loops` optimises it
   with Graduated Non-Convexity, so that one false loop cannot bend the map.
3. Every frame keeps its pose relative to its keyframe: ``T_world_f' = T_world_k' T_world_k^-1 T_world_f``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from gtvo.loops import LoopDetector
from gtvo.loops.closure_graph import LoopEdge, close_loops
from gtvo.datasets.sequence import Sequence
from gtvo.evaluation.trajectory import Trajectory

#: Odometry edge standard deviations between consecutive keyframes: rotation (rad), translation (m).
ODOMETRY_SIGMAS = (0.005, 0.05)


@dataclass
class LoopClosingResult:
    """The loop-closed trajectory and what was found.

    Attributes:
        trajectory: every frame, re-expressed after the keyframe pose graph was optimised.
        candidates: verified loop candidates ``(i, j)`` as frame indices of the sequence.
        accepted: per candidate, True when the robust optimisation kept it.
    """

    trajectory: Trajectory
    candidates: list[tuple[int, int]] = field(default_factory=list)
    accepted: list[bool] = field(default_factory=list)


def close_loops_of_run(seq: Sequence, est: Trajectory, frame_indices: list[int], keyframes: list[int],
                       progress: bool = False) -> LoopClosingResult:
    """Detect loops among a run's keyframes and return the loop-closed trajectory.

    Args:
        seq: the sequence the run read.
        est: the run's trajectory (one pose per processed frame).
        frame_indices: for each pose of ``est``, the frame index in ``seq`` (skipped frames
            have no pose).
        keyframes: positions in ``est`` of the keyframes.
        progress: show a progress bar.

    Returns the input trajectory unchanged when no loop is found.
    """
    kfs = sorted(set(int(k) for k in keyframes))
    if len(kfs) < 2:
        return LoopClosingResult(est)
    detector = LoopDetector(seq.camera)
    found = []
    it = kfs
    if progress:
        from tqdm import tqdm  # noqa: PLC0415

        it = tqdm(kfs, desc="loop detection", unit="kf", dynamic_ncols=True)
    for k in it:
        frame = seq.frame(frame_indices[k])
        if seq.kind == "stereo":
            detector.add_keyframe(k, frame.left, frame.right, T_world_cam=est.poses[k])
        else:
            detector.add_keyframe(k, frame.left, depth=frame.depth, T_world_cam=est.poses[k])
        found.extend(detector.query(k))
    if not found:
        return LoopClosingResult(est)
    rank = {k: r for r, k in enumerate(kfs)}
    edges = [LoopEdge(rank[c.i], rank[c.j], c.T_i_j, c.information) for c in found]
    sr, st = ODOMETRY_SIGMAS
    info = np.diag([1 / sr**2] * 3 + [1 / st**2] * 3)
    result = close_loops(est.poses[kfs], edges, odometry_information=info)
    poses = relocate_frames(est.poses, kfs, result.poses)
    traj = Trajectory(est.timestamps.copy(), poses, name=f"{est.name} (loop closed)")
    pairs = [(int(frame_indices[c.i]), int(frame_indices[c.j])) for c in found]
    return LoopClosingResult(traj, pairs, [bool(a) for a in result.accepted])


def relocate_frames(poses: NDArray[np.float64], keyframes: list[int],
                    new_keyframe_poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """Move every pose with its keyframe (the latest keyframe at or before it, by position)."""
    kfs = np.asarray(keyframes)
    owner = np.searchsorted(kfs, np.arange(len(poses)), side="right") - 1
    owner = np.maximum(owner, 0)
    correction = new_keyframe_poses @ np.linalg.inv(poses[kfs])  # (K, 4, 4)
    return correction[owner] @ poses
