"""The whole-log refinement joined to a run (:func:`refine_run`): what :func:`gtvo.run` does after
the window pass and loop closing when ``refine.enabled``.

The keyframes are refined (:func:`gtvo.refinement.refine_keyframes`, from the loop-closed poses
and with the accepted loop edges when loops were closed); the other frames move with their
keyframe and are then re-placed against the refined keyframes and their refined points by the
loop closing's frame refinement (:func:`gtvo.loops.closing.refine_result_frames`). When the
refinement does not run, is not kept, or is interrupted (Ctrl-C), the run's answer is the one it
would have been without it: the window's trajectory, and with loop closing its frames re-placed
against the loop-closed keyframes as ``--loop-closure`` alone does.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence as Seq, TypedDict

import numpy as np
from numpy.typing import NDArray

from factors.params import PhotometricConfig
from gtvo.core.interrupt import forget_interrupt, interrupt_requested, raise_if_interrupted
from gtvo.datasets.sequence import Sequence
from gtvo.errors import caused_by_interrupt
from gtvo.evaluation.accuracy import run_accuracy
from gtvo.evaluation.trajectory import Trajectory
from gtvo.frontend.stereo_depth import KeyframePoints
from gtvo.frontend.tracking import TrackingConfig
from gtvo.loops.closing import LoopClosingResult, refine_result_frames, relocate_frames
from gtvo.refinement.config import RefineConfig
from gtvo.refinement.solve import RefinementInput, RefinementResult, refine_keyframes
from gtvo.window.config import WindowConfig, WindowKeyframe
from gtvo.window.wheel import WheelCalibration
from gtvo.window.problem import WindowMembers, WindowSettings

F64 = NDArray[np.float64]

#: The one line a Ctrl-C during the refinement leaves (the run then writes its window-only outputs).
INTERRUPTED = "refinement interrupted (Ctrl-C): writing the window-only outputs"


class RefinementSummary(TypedDict, total=False):
    """The report's ``refine`` block (docs/evaluation.md, "report.json")."""

    ran: bool
    reason: str | None
    solver: str
    keyframes: int
    targets_mean: float
    iterations: int
    cost_before: float | None
    cost_after: float | None
    seconds: float
    loop_edges: int
    loop_edges_dropped: int
    frames_replaced: int
    wheel_calibration: list[float]
    window_ate_rmse_m: float | None
    window_ate_sim3_rmse_m: float | None
    window_scale_ratio: float | None


@dataclass
class RunRefinement:
    """What :func:`refine_run` leaves for the outputs.

    Attributes:
        trajectory: the run's trajectory, refined (the window's when the refinement was not kept).
        loop_result: the loop closing's result with its frames re-placed (against the refined
            keyframes when kept), None without loop closing.
        keyframe_poses: frame index -> 4x4 ``T_world_cam`` of the refined keyframes (empty: not kept).
        inverse_depths: frame index -> the keyframe's refined inverse depths (empty: not kept).
        covariances: frame index -> 6x6 pose covariance from the refined graph, None if none.
        summary: the report's ``refine`` block.
        frames_replaced: frames that at least one refined keyframe re-measured.
    """

    trajectory: Trajectory
    loop_result: LoopClosingResult | None
    keyframe_poses: dict[int, F64]
    inverse_depths: dict[int, F64]
    covariances: dict[int, F64] | None
    summary: RefinementSummary
    frames_replaced: int = 0


def refine_run(seq: Sequence, trajectory: Trajectory, frame_indices: list[int], keyframes: list[int],
               window_keyframes: Seq[WindowKeyframe], window: WindowConfig, config: RefineConfig, *,
               photometric: PhotometricConfig, tracking: TrackingConfig, rig_offset: F64 | None,
               keyframe_points: Mapping[int, KeyframePoints], odometry_covariances: Seq[F64 | None],
               refine: Seq[bool], loop_result: LoopClosingResult | None = None, progress: bool = False,
               warn: Callable[[str], None] = print, wheel: WheelCalibration | None = None) -> RunRefinement:
    """Refine a run's keyframes and re-place its frames (module docstring).

    Args:
        seq: the sequence the run read; trajectory: the window's trajectory (every frame).
        frame_indices: per pose of ``trajectory``, its frame index; keyframes: the keyframes'
            positions in ``trajectory`` (increasing).
        window_keyframes: every keyframe of the window pass with its images
            (:meth:`gtvo.window.SlidingWindowOptimizer.every_keyframe`).
        window, config, photometric, tracking: the run's settings.
        rig_offset: the window's final rig offset (None: the rectified model).
        keyframe_points: the VO's keyframe points by frame index; odometry_covariances: per pair of
            consecutive keyframes (:func:`gtvo.loops.closing.odometry_covariances`).
        refine: per pose, whether the frame may be re-placed (tracked frames).
        loop_result: the loop closing's result before its frame refinement (``refine_frames=False``).
        progress: progress bars; warn: where the one line of an interrupt or a refinement not kept goes.
        wheel: the run's wheel odometry and calibration (the window's), None without wheels
            (:func:`gtvo.refinement.refine_keyframes`).
    """
    kfs = sorted(set(int(k) for k in keyframes))
    closed = loop_result is not None and any(loop_result.accepted)
    edges = [e for e, a in zip(loop_result.measured_edges, loop_result.accepted) if a] if loop_result else []
    base = loop_result.trajectory if loop_result is not None else trajectory
    res: RefinementResult | None = None
    out = RunRefinement(trajectory, loop_result, {}, {}, None, {})
    try:
        run = RefinementInput(WindowMembers(seq.pinhole, getattr(seq.camera, "baseline", None), window_keyframes),
                              WindowSettings(window, photometric, on_iteration=lambda it, cost: raise_if_interrupted()),
                              rig_offset, (wheel,), edges, loop_result.keyframe_poses if closed else None,
                              odometry_covariances)
        res = refine_keyframes(run, config, progress)
        if res.ran:
            out = _re_place(seq, base, frame_indices, kfs, res, keyframe_points, odometry_covariances, tracking,
                            photometric, refine, loop_result, trajectory, progress)
    except BaseException as exc:  # noqa: BLE001 (an interrupt, perhaps inside compiled code)
        if not (isinstance(exc, KeyboardInterrupt) or caused_by_interrupt(exc) or interrupt_requested()):
            raise
        forget_interrupt()
        warn(INTERRUPTED)
        res = dataclasses.replace(res, ran=False, reason="interrupted (Ctrl-C)") if res is not None else None
        out = RunRefinement(trajectory, loop_result, {}, {}, None, {})
    if res is not None and not res.ran and res.reason != "interrupted (Ctrl-C)":
        warn(f"refinement not kept: {res.reason}")
    if not out.keyframe_poses and loop_result is not None:  # the loop closing's own frame refinement
        refine_result_frames(seq, loop_result, frame_indices, kfs, progress, odometry_covariances, keyframe_points,
                             tracking, refine, photometric=photometric)
    out.summary = _summary(res, config, len(window_keyframes), out, seq, trajectory, loop_result is None)
    return out


def _re_place(seq: Sequence, base: Trajectory, frame_indices: list[int], kfs: list[int], res: RefinementResult,
              keyframe_points: Mapping[int, KeyframePoints], odometry_covariances: Seq[F64 | None],
              tracking: TrackingConfig, photometric: PhotometricConfig, refine: Seq[bool],
              loop_result: LoopClosingResult | None, window_trajectory: Trajectory, progress: bool) -> RunRefinement:
    """The frames of ``base`` moved with their refined keyframes, then re-placed against them; with
    loop closing the refined trajectory is the loop-closed one (``trajectory.tum`` stays the
    window's), without it the run's."""
    poses = {kf.index: kf.pose.matrix() for kf in res.keyframes}
    depths = {kf.index: kf.inverse_depth.copy() for kf in res.keyframes}
    moved = relocate_frames(base.poses, kfs, np.stack([poses[int(frame_indices[k])] for k in kfs]))
    holder = LoopClosingResult(Trajectory(base.timestamps.copy(), moved, name=base.name), keyframe_poses=poses)
    points = {i: dataclasses.replace(p, inverse_depth=depths[i]) if i in depths else p
              for i, p in keyframe_points.items()}
    refine_result_frames(seq, holder, frame_indices, kfs, progress, odometry_covariances, points, tracking, refine,
                         photometric=photometric)
    n = int(np.count_nonzero(holder.frame_hosts)) if holder.frame_hosts is not None else 0
    if loop_result is None:
        return RunRefinement(holder.trajectory, None, poses, depths, res.covariances, {}, n)
    loop_result.trajectory, loop_result.keyframe_poses = holder.trajectory, poses
    loop_result.frame_hosts = holder.frame_hosts
    return RunRefinement(window_trajectory, loop_result, poses, depths, res.covariances, {}, n)


def _summary(res: RefinementResult | None, config: RefineConfig, n_keyframes: int, out: RunRefinement,
             seq: Sequence, window_trajectory: Trajectory, replaces_window: bool) -> RefinementSummary:
    """The report's ``refine`` block; ``window_*``: the window's accuracy, when the refinement
    replaced the run's trajectory (without loop closing; with it, the report's own ``ate_*`` are
    the window's and ``loop_closed_*`` the refined ones)."""
    ran = bool(out.keyframe_poses)
    block: RefinementSummary = {
        "ran": ran, "reason": None if ran else (res.reason if res is not None else "interrupted (Ctrl-C)"),
        "solver": config.solver, "keyframes": n_keyframes,
        "targets_mean": None if res is None else round(res.targets_mean, 3),
        "iterations": 0 if res is None else res.iterations,
        "cost_before": None if res is None else res.cost_before, "cost_after": None if res is None else res.cost_after,
        "seconds": 0.0 if res is None else round(res.seconds, 3),
        "loop_edges": 0 if res is None else res.loop_edges,
        "loop_edges_dropped": 0 if res is None else res.loop_edges_dropped}
    block["frames_replaced"] = out.frames_replaced
    if ran and res is not None and res.wheel_calibration is not None:
        block["wheel_calibration"] = [float(x) for x in res.wheel_calibration]
    if replaces_window and ran:
        acc = run_accuracy(seq, window_trajectory)
        block.update(window_ate_rmse_m=acc.get("ate_rmse_m"), window_ate_sim3_rmse_m=acc.get("ate_sim3_rmse_m"),
                     window_scale_ratio=acc.get("scale_ratio"))
    return block
