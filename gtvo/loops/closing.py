"""Loop closing after a VO run: place recognition over the keyframes, a robust keyframe pose graph.

1. Every keyframe of the run goes into a :class:`gtvo.loops.LoopDetector` (ORB bag of words,
   verified by PnP RANSAC on its stereo or RGB-D points) and is queried against the earlier ones.
2. Each verified loop is re-measured by direct alignment (:func:`gtvo.loops.direct_refinement.refine_loop`):
   the candidate's image tracked against the query keyframe's points from the PnP pose, the way
   the VO measures its odometry edges; a loop the tracker cannot align is dropped.
3. The keyframe poses become a pose graph: consecutive keyframes are joined by their VO relative
   pose (odometry edges) with the covariance of the tracking that linked them, every loop by its
   direct relative pose and covariance (``BetweenFactorPose3``), and
   :func:`gtvo.loops.closure_graph.close_loops` optimises it with Graduated Non-Convexity, so
   that one false loop cannot bend the map. Both kinds of edge come from the same photometric
   model, so neither is on another scale of confidence than the other (docs/loop_closure.md).
4. Every frame keeps its pose relative to its keyframe: ``T_world_f' = T_world_k' T_world_k^-1 T_world_f``;
   with ``refine_frames``, every tracked frame is then re-estimated against all final keyframes
   within the tracker's range (:func:`gtvo.loops.frame_refinement.refine_frames`): its single
   alignment against one keyframe is its whole error relative to that keyframe otherwise.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Mapping, Sequence as Seq

import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import StereoCamera
from gtvo.core.image import to_float_gray
from gtvo.datasets.sequence import Frame, Sequence
from gtvo.errors import InputError
from gtvo.evaluation.trajectory import Trajectory
from gtvo.frontend.rgbd import rgbd_keyframe_points
from gtvo.frontend.stereo_depth import KeyframePoints, init_keyframe_points
from gtvo.frontend.tracking import PhotometricConfig, TrackingConfig
from gtvo.loops import LoopCandidate, LoopDetector
from gtvo.config.sections.loops import LoopDetectorConfig
from gtvo.loops.closure_graph import LoopEdge, close_loops
from gtvo.loops.direct_refinement import refine_loop_both_ways
from gtvo.loops.frame_refinement import refine_frames as refine_frame_poses
from gtvo.odometry.result import OdometryResult, odometry_covariances
from gtvo.report import LoopClosureSummary

__all__ = ["LOOP_CLOSURE_SOLVER", "ODOMETRY_SIGMAS", "REFINEMENT_POINTS", "LoopClosingResult", "LoopClosureSummary",
           "close_loops_of_run", "odometry_covariances", "odometry_informations", "refine_result_frames",
           "relocate_frames", "run_loop_closing"]

#: Odometry edge standard deviations, rotation (rad) and translation (m), for consecutive keyframes
#: that no successful tracking links (the first keyframe after a re-initialisation, or a run whose
#: frame estimates are not given): a weak link, since such a pose is a motion-model guess.
ODOMETRY_SIGMAS = (0.005, 0.05)

#: Points per keyframe when a keyframe's points have to be made afresh for the direct refinement
#: (the VO's default, OdometryConfig.frontend.points_per_keyframe).
REFINEMENT_POINTS = 300

#: How the loops are closed, for the report: GTSAM's GncLMOptimizer, then LM on the kept loops.
LOOP_CLOSURE_SOLVER = "gtsam_gnc_lm"


@dataclass
class LoopClosingResult:
    """The loop-closed trajectory and what was found.

    Attributes:
        trajectory: every frame, re-expressed after the keyframe pose graph was optimised.
        candidates: verified loop candidates ``(i, j)`` as frame indices of the sequence.
        accepted: per candidate, True when the robust optimisation kept it.
        unrefined: verified loops ``(i, j)`` that direct alignment could not measure (not in the graph).
        keyframe_poses: the keyframes' poses after loop closing, ``{frame index in seq: 4x4 T_world_cam}``
            (the input's when no loop was closed).
        frame_hosts: per pose of ``trajectory``, how many keyframes re-measured it (``refine_frames``;
            0: moved with its keyframe), None when frames were not refined.
        measured_edges: per candidate, its measured relative pose and information by frame index
            (the whole-log refinement's loop edges, those ``accepted``).
    """

    trajectory: Trajectory
    candidates: list[tuple[int, int]] = field(default_factory=list)
    accepted: list[bool] = field(default_factory=list)
    unrefined: list[tuple[int, int]] = field(default_factory=list)
    keyframe_poses: dict[int, NDArray[np.float64]] = field(default_factory=dict)
    frame_hosts: NDArray[np.int64] | None = None
    #: per candidate, its direct measurement as a :class:`LoopEdge` between frame indices ``(i, j)``
    measured_edges: list[LoopEdge] = field(default_factory=list)

    def summary(self) -> LoopClosureSummary:
        """``loops_detected`` (verified loops, measured or not), ``loops_unrefined`` (those direct
        alignment could not measure), ``loops_accepted`` (kept by the robust optimisation),
        ``loop_closure_solver`` (:data:`LOOP_CLOSURE_SOLVER`), ``frames_refined`` (frames that at
        least one keyframe re-measured) and ``frame_refinement_hosts_mean`` (over those, how many
        keyframes did; None if none)."""
        hosts = self.frame_hosts if self.frame_hosts is not None else np.zeros(0, np.int64)
        return {"loops_detected": len(self.candidates) + len(self.unrefined),
                "loops_unrefined": len(self.unrefined),
                "loops_accepted": int(sum(self.accepted)),
                "loop_closure_solver": LOOP_CLOSURE_SOLVER,
                "frames_refined": int(np.count_nonzero(hosts)),
                "frame_refinement_hosts_mean": float(hosts[hosts > 0].mean()) if np.any(hosts > 0) else None}


@dataclass(frozen=True)
class _Tracker:
    """The tracker's settings and photometric model that re-measure loops and frames."""

    config: TrackingConfig | None
    photometric: PhotometricConfig | None


def run_loop_closing(result: OdometryResult, seq: Sequence, progress: bool = False) -> OdometryResult:
    """Loop closing as a stage of a run (``loops.enabled``; otherwise ``result`` itself): the loops
    among ``result``'s keyframes closed (:func:`close_loops_of_run`, with the run's settings, its
    keyframes' points and the covariances of their links) and a copy of ``result`` returned with the
    outcome (``loops``) and the loop-closed keyframe poses as the map's (``map_poses``). Every tracked
    frame is then re-estimated against the final keyframes, unless the whole-log refinement follows
    (``result.window_keyframes``), which re-places the frames itself (:func:`gtvo.refinement.run.run_refinement`).
    """
    config = result.config
    if not config.loops.enabled:
        return result
    closed = close_loops_of_run(seq, result.trajectory, result.frame_indices, result.keyframe_positions,
                                progress=progress, odometry_covariances=result.link_covariances,
                                keyframe_points=result.keyframe_points, tracking_config=config.tracking,
                                refine_frames=result.window_keyframes is None, refine=result.tracked,
                                detector_config=config.loops.detector, photometric=config.photometric)
    return dataclasses.replace(result, loops=closed, map_poses=closed.keyframe_poses)


def close_loops_of_run(seq: Sequence, est: Trajectory, frame_indices: list[int], keyframes: list[int],
                       progress: bool = False, odometry_covariances: Seq[NDArray[np.float64] | None] | None = None,
                       keyframe_points: Mapping[int, KeyframePoints] | None = None,
                       tracking_config: TrackingConfig | None = None, refine_frames: bool = False,
                       refine: Seq[bool] | None = None, *, detector_config: LoopDetectorConfig | None = None,
                       photometric: PhotometricConfig | None = None) -> LoopClosingResult:
    """Detect loops among a run's keyframes and return the loop-closed trajectory.

    Args:
        seq: the sequence the run read.
        est: the run's trajectory (one pose per processed frame).
        frame_indices: for each pose of ``est``, the frame index in ``seq`` (skipped frames
            have no pose).
        keyframes: positions in ``est`` of the keyframes.
        progress: show a progress bar.
        odometry_covariances: per pair of consecutive keyframes (``len(keyframes) - 1``), the 6x6
            covariance of their relative pose (:func:`odometry_covariances`), or None where no
            tracking links them; None for all: every edge gets :data:`ODOMETRY_SIGMAS`.
        keyframe_points: the VO's points of each keyframe (window-refined depths), by frame index
            in ``seq``, hosting the direct refinement of a loop; a keyframe missing here gets points
            made afresh from its stereo pair (less accurate: one pair's depths) or its depth image.
        tracking_config, photometric: the tracker's settings and photometric model for the
            refinement (the VO's ``OdometryConfig.tracking`` and ``.photometric``; default their defaults).
        refine_frames: after loop closing (also when no loop was found), re-estimate every frame
            that is not a keyframe against the final keyframes
            (:func:`gtvo.loops.frame_refinement.refine_frames`, the keyframes' points from
            ``keyframe_points`` or made afresh).
        refine: with ``refine_frames``, per pose of ``est``, whether it may be re-estimated
            (default every non-keyframe; leave out poses that are predictions: lost or suspect frames).
        detector_config: the place recognition's settings (a run's ``OdometryConfig.loops.detector``;
            default :class:`LoopDetectorConfig`).

    Without ``refine_frames`` the input trajectory is returned unchanged when no loop is found.
    """
    kfs = sorted(set(int(k) for k in keyframes))
    if not kfs:
        return LoopClosingResult(est)
    tracker = _Tracker(tracking_config, photometric)
    result = _close(seq, est, frame_indices, kfs, progress, odometry_covariances, keyframe_points, tracker,
                    detector_config)
    if refine_frames and len(kfs) >= 2:
        refine_result_frames(seq, result, frame_indices, kfs, progress, odometry_covariances, keyframe_points,
                             tracking_config, refine, photometric=photometric)
    return result


def _close(seq: Sequence, est: Trajectory, frame_indices: list[int], kfs: list[int], progress: bool,
           odometry_covariances: Seq[NDArray[np.float64] | None] | None,
           keyframe_points: Mapping[int, KeyframePoints] | None, tracker: _Tracker,
           detector_config: LoopDetectorConfig | None) -> LoopClosingResult:
    """Detection, direct re-measurement and the robust keyframe pose graph (steps 1-3)."""
    unchanged = {int(frame_indices[k]): est.poses[k].copy() for k in kfs}
    if len(kfs) < 2:
        return LoopClosingResult(est, keyframe_poses=unchanged)
    found = _detect(seq, est, frame_indices, kfs, progress, detector_config)
    if not found:
        return LoopClosingResult(est, keyframe_poses=unchanged)
    rank = {k: r for r, k in enumerate(kfs)}
    edges, pairs, unrefined, measured = [], [], [], []
    for c in found:
        fi, fj = int(frame_indices[c.i]), int(frame_indices[c.j])
        refined = _refine(seq, c, fi, fj, keyframe_points, tracker)
        if refined is None:
            unrefined.append((fi, fj))
        else:
            edges.append(LoopEdge(rank[c.i], rank[c.j], refined.T_i_j, refined.information))
            pairs.append((fi, fj))
            measured.append(LoopEdge(fi, fj, refined.T_i_j, refined.information))
    if not edges:
        return LoopClosingResult(est, unrefined=unrefined, keyframe_poses=unchanged)
    info = odometry_informations(len(kfs), odometry_covariances)
    result = close_loops(est.poses[kfs], edges, odometry_information=info)
    poses = relocate_frames(est.poses, kfs, result.poses)
    traj = Trajectory(est.timestamps.copy(), poses, name=f"{est.name} (loop closed)")
    kf_poses = {int(frame_indices[k]): result.poses[r].copy() for r, k in enumerate(kfs)}
    return LoopClosingResult(traj, pairs, [bool(a) for a in result.accepted], unrefined, kf_poses,
                             measured_edges=measured)


def refine_result_frames(seq: Sequence, result: LoopClosingResult, frame_indices: list[int], kfs: list[int],
                         progress: bool, odometry_covariances: Seq[NDArray[np.float64] | None] | None,
                         keyframe_points: Mapping[int, KeyframePoints] | None,
                         tracking_config: TrackingConfig | None, refine: Seq[bool] | None, *,
                         photometric: PhotometricConfig | None = None) -> None:
    """Step 4 with ``refine_frames``: ``result.trajectory`` re-estimated frame by frame against its
    keyframes (in place; ``frame_hosts`` set); the arguments as :func:`close_loops_of_run`'s
    (``kfs``: its sorted keyframe positions). Also what the whole-log refinement re-places its
    non-keyframes with (:mod:`gtvo.refinement.run`)."""
    tracker = _Tracker(tracking_config, photometric)
    traj = result.trajectory
    points = []
    for k in kfs:
        fi = int(frame_indices[k])
        pts = keyframe_points.get(fi) if keyframe_points is not None else None
        points.append(_fresh_points(seq, seq.frame(fi)) if pts is None else pts)
    edge_cov = np.linalg.inv(odometry_informations(len(kfs), odometry_covariances))
    refined = refine_frame_poses(seq.pinhole, lambda p: seq.frame(int(frame_indices[p])).left, traj.poses, kfs,
                                 points, edge_cov, refine=refine, config=tracker.config, progress=progress,
                                 photometric=tracker.photometric)
    name = traj.name if traj.name.endswith("(loop closed)") else f"{traj.name} (loop closed)"
    result.trajectory = Trajectory(traj.timestamps.copy(), refined.poses, name=name)
    result.frame_hosts = refined.hosts


def _detect(seq: Sequence, est: Trajectory, frame_indices: list[int], kfs: list[int],
            progress: bool, config: LoopDetectorConfig | None = None) -> list[LoopCandidate]:
    """Every keyframe added to a :class:`LoopDetector` and queried: the verified loops (PnP)."""
    detector = LoopDetector(seq.camera, config)
    found: list[LoopCandidate] = []
    it: Seq[int] = kfs
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
    return found


def _refine(seq: Sequence, c: LoopCandidate, fi: int, fj: int, points: Mapping[int, KeyframePoints] | None,
            tracker: _Tracker):
    """The loop ``c`` (query frame ``fi``, candidate ``fj``) re-measured by direct alignment both
    ways (:func:`refine_loop_both_ways`), or None."""
    host, target = seq.frame(fi), seq.frame(fj)
    pi = points.get(fi) if points is not None else None
    pj = points.get(fj) if points is not None else None
    pi = _fresh_points(seq, host) if pi is None else pi
    pj = _fresh_points(seq, target) if pj is None else pj
    return refine_loop_both_ways(seq.pinhole, host.left, pi, target.left, pj, c.T_i_j, tracker.config,
                                 photometric=tracker.photometric)


def _fresh_points(seq: Sequence, frame: Frame) -> KeyframePoints:
    """A keyframe's points made from its images as the VO makes them (stereo pair or depth image)."""
    if isinstance(seq.camera, StereoCamera):
        return init_keyframe_points(frame.left, frame.right, seq.camera, target=REFINEMENT_POINTS)
    return rgbd_keyframe_points(to_float_gray(frame.left, f"frame {frame.index} image"), frame.depth,
                                REFINEMENT_POINTS)


def odometry_informations(n_keyframes: int, covariances: Seq[NDArray[np.float64] | None] | None
                          ) -> NDArray[np.float64]:
    """(n_keyframes - 1, 6, 6) information of the odometry edges: the inverse covariance, or
    :data:`ODOMETRY_SIGMAS` where there is none."""
    sr, st = ODOMETRY_SIGMAS
    weak = np.diag([1 / sr**2] * 3 + [1 / st**2] * 3)
    info = np.tile(weak, (n_keyframes - 1, 1, 1))
    if covariances is None:
        return info
    if len(covariances) != n_keyframes - 1:
        raise InputError(f"{len(covariances)} odometry covariances for {n_keyframes} keyframes "
                         f"(expected {n_keyframes - 1})")
    for k, C in enumerate(covariances):
        if C is not None:
            C = 0.5 * (np.asarray(C, float) + np.asarray(C, float).T)
            info[k] = np.linalg.inv(C)
    return info


def relocate_frames(poses: NDArray[np.float64], keyframes: list[int],
                    new_keyframe_poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """Move every pose with its keyframe (the latest keyframe at or before it, by position)."""
    kfs = np.asarray(keyframes)
    owner = np.searchsorted(kfs, np.arange(len(poses)), side="right") - 1
    owner = np.maximum(owner, 0)
    correction = new_keyframe_poses @ np.linalg.inv(poses[kfs])  # (K, 4, 4)
    return correction[owner] @ poses
