"""The whole-log refinement joined to a run: the stage :func:`run_refinement` (what :func:`gtvo.run` does
after the window pass and loop closing when ``refine.enabled``) over :func:`refine_run`.

The keyframes are refined (:func:`gtvo.refinement.refine_keyframes`, from the loop-closed poses
and with the accepted loop edges when loops were closed); the other frames move with their
keyframe and are then re-placed against the refined keyframes and their refined points by the
loop closing's frame refinement (:func:`gtvo.loops.closing.refine_result_frames`). When the
refinement does not run or is not kept, the run's answer is the one it would have been without
it: the window's trajectory, and with loop closing its frames re-placed against the loop-closed
keyframes as ``--loop-closure`` alone does. Ctrl-C during it stops the run as anywhere else.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np
from numpy.typing import NDArray

from gtvo.core.interrupt import raise_if_interrupted
from gtvo.datasets.sequence import Sequence
from gtvo.evaluation.accuracy import run_accuracy
from gtvo.evaluation.trajectory import Trajectory
from gtvo.frontend.stereo_depth import KeyframePoints
from gtvo.loops.closing import LoopClosingResult, refine_result_frames, relocate_frames
from gtvo.odometry.result import OdometryResult
from gtvo.report import RefinementSummary
from gtvo.refinement.solve import RefinementInput, RefinementResult, refine_keyframes
from gtvo.window.problem import WindowMembers, WindowSettings

F64 = NDArray[np.float64]

#: ``covariances.npz``'s source when the whole-log refinement was kept (its graph's marginals).
REFINED_COVARIANCES = {"gtsam": "gtsam.Marginals of the whole-log refinement's graph",
                       "handrolled": "inverse of the whole-log refinement's reduced Hessian (hand-rolled)"}


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


def run_refinement(result: OdometryResult, seq: Sequence, progress: bool = False,
                   warn: Callable[[str], None] = print) -> OdometryResult:
    """The whole-log refinement as a stage of a run: ``result`` itself when the window kept no
    keyframes for it (``refine.enabled`` false, or track mode), else a copy with the refinement's
    outcome (:func:`refine_run`, with the run's settings and what the window left): the trajectory
    refined (without loop closing), the loop closing's frames re-placed against the refined keyframes
    (its own copy: ``result.loops`` is left as it was), the keyframes' refined depths and pose
    covariances, the map on the refined keyframes and the report's ``refine`` block. When the
    refinement is not kept the run's answer stays the one it would have been without it.
    """
    if result.window_keyframes is None:
        return result
    loops = None if result.loops is None else dataclasses.replace(result.loops)  # type: ignore[type-var]
    refined = refine_run(seq, result, loops, progress, warn)
    closed = refined.loop_result
    map_poses = closed.keyframe_poses if closed is not None else (refined.keyframe_poses or None)
    return result.with_refined_keyframes(refined.inverse_depths, refined.covariances,
                                         REFINED_COVARIANCES[result.config.refine.solver],
                                         trajectory=refined.trajectory, loops=closed, refinement=refined.summary,
                                         map_poses=map_poses)


@dataclass(frozen=True)
class _Job:
    """One refinement of a run: the sequence it read, the odometry's result (trajectory, keyframes,
    their points and link covariances, the window's keyframes, rig offset and wheels, the settings),
    the keyframes' positions in the trajectory and whether to show progress bars."""

    seq: Sequence
    odometry: OdometryResult
    keyframes: list[int]
    progress: bool

    def re_place(self, result: LoopClosingResult, points: Mapping[int, KeyframePoints]) -> None:
        """Re-place the tracked frames of ``result`` against its keyframes and ``points``
        (:func:`gtvo.loops.closing.refine_result_frames`)."""
        odo, config = self.odometry, self.odometry.config
        refine_result_frames(self.seq, result, odo.frame_indices, self.keyframes, self.progress,
                             odo.link_covariances, points, config.tracking, odo.tracked, photometric=config.photometric)


def refine_run(seq: Sequence, odometry: OdometryResult, loop_result: LoopClosingResult | None = None,
               progress: bool = False, warn: Callable[[str], None] = print) -> RunRefinement:
    """Refine a run's keyframes and re-place its frames (module docstring).

    Args:
        seq: the sequence the run read.
        odometry: the odometry's result with the window's keyframes kept for the refinement
            (``window_keyframes``; its trajectory, frames, keyframe points and link covariances, the
            window's final rig offset and wheel calibration, and the run's settings are used).
        loop_result: the loop closing's result before its frame refinement (``refine_frames=False``).
        progress: progress bars; warn: where the one line of a refinement not kept goes.
    """
    if odometry.window_keyframes is None:
        raise ValueError("refine_run: the odometry kept no window keyframes (refine.enabled was off)")
    job = _Job(seq, odometry, sorted(set(int(k) for k in odometry.keyframe_positions)), progress)
    config, trajectory = odometry.config, odometry.trajectory
    closed = loop_result is not None and any(loop_result.accepted)
    edges = [e for e, a in zip(loop_result.measured_edges, loop_result.accepted) if a] if loop_result else []
    out = RunRefinement(trajectory, loop_result, {}, {}, None, {})
    # Ctrl-C here is Ctrl-C everywhere (README, "Failures and exit codes"): the run stops, exit 130,
    # the earlier outputs kept
    run = RefinementInput(WindowMembers(seq.pinhole, getattr(seq.camera, "baseline", None), odometry.window_keyframes),
                          WindowSettings(config.window, config.photometric,
                                         on_iteration=lambda it, cost: raise_if_interrupted()),
                          odometry.rig_offset, (odometry.wheel, odometry.imu), edges,
                          loop_result.keyframe_poses if closed else None, odometry.link_covariances)
    res = refine_keyframes(run, config.refine, progress)
    if res.ran:
        out = _re_place(job, res, loop_result)
    else:
        warn(f"refinement not kept: {res.reason}")
    if not out.keyframe_poses and loop_result is not None:  # the loop closing's own frame refinement
        job.re_place(loop_result, odometry.keyframe_points)
    out.summary = _summary(job, res, out, loop_result is None)
    return out


def _re_place(job: _Job, res: RefinementResult, loop_result: LoopClosingResult | None) -> RunRefinement:
    """The frames of the run (the loop-closed ones with loop closing) moved with their refined
    keyframes, then re-placed against them; with loop closing the refined trajectory is the
    loop-closed one (``trajectory.tum`` stays the window's), without it the run's."""
    odo, kfs = job.odometry, job.keyframes
    base = loop_result.trajectory if loop_result is not None else odo.trajectory
    poses = {kf.index: kf.pose.matrix() for kf in res.keyframes}
    depths = {kf.index: kf.inverse_depth.copy() for kf in res.keyframes}
    frame_indices = odo.frame_indices
    moved = relocate_frames(base.poses, kfs, np.stack([poses[int(frame_indices[k])] for k in kfs]))
    holder = LoopClosingResult(Trajectory(base.timestamps.copy(), moved, name=base.name), keyframe_poses=poses)
    points = {i: dataclasses.replace(p, inverse_depth=depths[i]) if i in depths else p
              for i, p in odo.keyframe_points.items()}
    job.re_place(holder, points)
    n = int(np.count_nonzero(holder.frame_hosts)) if holder.frame_hosts is not None else 0
    if loop_result is None:
        return RunRefinement(holder.trajectory, None, poses, depths, res.covariances, {}, n)
    loop_result.trajectory, loop_result.keyframe_poses = holder.trajectory, poses
    loop_result.frame_hosts = holder.frame_hosts
    return RunRefinement(odo.trajectory, loop_result, poses, depths, res.covariances, {}, n)


def _summary(job: _Job, res: RefinementResult, out: RunRefinement, replaces_window: bool) -> RefinementSummary:
    """The report's ``refine`` block; ``window_*``: the window's accuracy, when the refinement
    replaced the run's trajectory (without loop closing; with it, the report's own ``ate_*`` are
    the window's and ``loop_closed_*`` the refined ones)."""
    ran = bool(out.keyframe_poses)
    config = job.odometry.config.refine
    block: RefinementSummary = {
        "ran": ran, "reason": None if ran else res.reason,
        "solver": config.solver, "keyframes": len(job.odometry.window_keyframes or ()),
        "targets_mean": round(res.targets_mean, 3), "iterations": res.iterations,
        "cost_before": res.cost_before, "cost_after": res.cost_after, "seconds": round(res.seconds, 3),
        "loop_edges": res.loop_edges, "loop_edges_dropped": res.loop_edges_dropped}
    block["frames_replaced"] = out.frames_replaced
    if ran and res.wheel_calibration is not None:
        block["wheel_calibration"] = [float(x) for x in res.wheel_calibration]
    imu = job.odometry.imu
    if ran and imu is not None:  # the IMU factors the whole-log graph carried (its last build's count)
        block["imu_factors"] = imu.factors_added
    if replaces_window and ran:
        acc = run_accuracy(job.seq, job.odometry.trajectory)
        block.update(window_ate_rmse_m=acc.get("ate_rmse_m"), window_ate_sim3_rmse_m=acc.get("ate_sim3_rmse_m"),
                     window_scale_ratio=acc.get("scale_ratio"))
    return block
