"""What the odometry hands to the rest of a run: :class:`OdometryResult`, one value.

After the last frame the odometry's state is read once (:func:`gtvo.odometry.summary.odometry_result`)
into this value: every frame's estimate and the trajectory, the keyframes with their optimised
poses and points, what the window leaves for the whole-log refinement (its keyframes with their
images, the rig offset, the wheel calibration), the keyframes' pose covariances, the covariances of
the links between consecutive keyframes (computed once, read by loop closing and the refinement),
the odometry's figures and its clock. The stages that follow take it and return a new one
(:func:`gtvo.loops.closing.run_loop_closing`, :func:`gtvo.refinement.run.run_refinement`): nothing writes into
the odometry after its run (DSO's single hand-over between front end and back end; KISS-ICP's
pipeline of steps). The report is built from the last one (:func:`gtvo.report.run_report`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping, Protocol, Sequence

import numpy as np
from numpy.typing import NDArray

from gtvo.config import OdometryConfig
from gtvo.core.camera import PinholeCamera
from gtvo.core.map_points import MapPoints, constrained_mask
from gtvo.core.timing import StageClock
from gtvo.evaluation.covariances import KeyframeCovariances
from gtvo.evaluation.trajectory import Trajectory
from gtvo.frontend.stereo_depth import KeyframePoints
from gtvo.odometry.estimates import FrameEstimate, FrameOutcome
from gtvo.report import LoopClosureSummary, OdometrySummary, RefinementSummary
from gtvo.window.config import WindowKeyframe
from gtvo.window.imu import ImuWindow
from gtvo.window.wheel import WheelCalibration

F64 = NDArray[np.float64]

#: Outcomes whose pose comes from tracking (the others are keyframes or predictions): the frames
#: that loop closing and the refinement re-estimate against the final keyframes.
TRACKED_OUTCOMES = (FrameOutcome.TRACKED, FrameOutcome.RECOVERED)


@dataclass(frozen=True)
class MapKeyframe:
    """A keyframe as the map sees it: ``index`` (its frame), ``T_world_cam`` (4x4, its pose at the end
    of the odometry), ``points`` (its points with their optimised depths) and ``observed`` (per point,
    the most other keyframes one window optimisation compared it with; None when none included it)."""

    index: int
    T_world_cam: F64
    points: KeyframePoints
    observed: NDArray[np.int64] | None


def keyframe_map(pinhole: PinholeCamera, keyframes: Sequence[MapKeyframe],
                 poses: Mapping[int, F64] | None = None) -> MapPoints:
    """The keyframes' points whose depth the run constrains, in the world frame (what ``points.ply``
    holds; :meth:`gtvo.odometry.VisualOdometry.map_points`): inverse depth positive, relative depth
    sigma bounded and, for keyframes that a window optimisation included, seen from enough keyframes
    in one (:mod:`gtvo.core.map_points`); the rest counted. ``poses``: ``{index: 4x4 T_world_cam}``
    to place keyframes elsewhere than at their own poses; a keyframe missing from it keeps its own."""
    pts, vals = [np.zeros((0, 3))], [np.zeros(0)]
    left_out: dict[str, int] = {}
    for kf in keyframes:
        keep, out = constrained_mask(kf.points.inverse_depth, kf.points.variance,
                                     None if kf.observed is None else 1 + kf.observed)
        for k, v in out.items():
            left_out[k] = left_out.get(k, 0) + v
        T = kf.T_world_cam if poses is None or kf.index not in poses else np.asarray(poses[kf.index], dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            X = pinhole.backproject_inverse_depth(kf.points.pixels, kf.points.inverse_depth)
        pts.append((X @ T[:3, :3].T + T[:3, 3])[keep])
        vals.append(np.asarray(kf.points.intensity, dtype=float)[keep])
    return MapPoints(np.concatenate(pts), np.concatenate(vals), left_out)


class LoopClosing(Protocol):
    """What the later steps read of the loop closing's outcome (:class:`gtvo.loops.closing.LoopClosingResult`)."""

    #: every frame after loop closing (``trajectory_loop_closed.tum``)
    trajectory: Trajectory
    #: the keyframes' poses after loop closing by frame index (4x4)
    keyframe_poses: dict[int, F64]

    def summary(self) -> LoopClosureSummary:
        """What loop closing found, as ``report.json`` keys."""


@dataclass(frozen=True)
class OdometryResult:
    """A run's odometry as one value (module docstring); the stages return copies with their part set.

    Attributes:
        config: the run's settings.
        pinhole: the (left) camera.
        estimates: one :class:`FrameEstimate` per processed frame.
        trajectory: the run's trajectory, every frame (``trajectory.tum``): the odometry's, or the
            refinement's when it replaced it.
        summary: the odometry's figures (:class:`gtvo.report.OdometrySummary`).
        keyframes: every keyframe, in order, with its pose and points (the refinement's depths once
            it was kept).
        link_covariances: per pair of consecutive keyframes, the covariance of their relative pose
            from tracking, or None (:func:`odometry_covariances`).
        covariances: the keyframes' pose covariances (the refined graph's where the refinement was
            kept), None when none were computed (track mode, ``window.covariances`` false).
        window_keyframes: every keyframe of the window with its images, kept for the whole-log
            refinement (``refine.enabled``, window mode), else None.
        rig_offset: the window's final rig offset (px), None: the rectified model.
        wheel: the window's wheel calibration, None without wheel odometry or refinement.
        imu: the window's IMU (its keyframes' velocities and biases, gravity), None without an IMU
            or refinement (the whole-log refinement carries its factors: docs/refinement.md).
        clock: the run's stage clock (None: untimed).
        loops: the loop closing's outcome, None when it did not run.
        refinement: the refinement's ``refine`` block, None when it was not asked for.
        map_poses: where the map's keyframes go (loop-closed or refined), None: their own poses.
        gravity_rotation: ``R_aligned_world``, the rotation from the odometry's world to the
            gravity-aligned one (an initialised IMU: :func:`gtvo.odometry.imu.gravity_aligned` writes
            the outputs there; docs/imu.md), None without one.
    """

    config: OdometryConfig
    pinhole: PinholeCamera
    estimates: tuple[FrameEstimate, ...]
    trajectory: Trajectory
    summary: OdometrySummary
    keyframes: tuple[MapKeyframe, ...]
    link_covariances: tuple[F64 | None, ...]
    covariances: KeyframeCovariances | None
    window_keyframes: tuple[WindowKeyframe, ...] | None = None
    rig_offset: F64 | None = None
    wheel: WheelCalibration | None = None
    imu: ImuWindow | None = None
    clock: StageClock | None = None
    loops: LoopClosing | None = None
    refinement: RefinementSummary | None = None
    map_poses: Mapping[int, F64] | None = None
    gravity_rotation: F64 | None = None

    @property
    def frame_indices(self) -> list[int]:
        """Per pose of :attr:`trajectory`, its frame index in the sequence."""
        return [e.index for e in self.estimates]

    @property
    def keyframe_positions(self) -> list[int]:
        """The keyframes' positions in :attr:`trajectory`."""
        return [p for p, e in enumerate(self.estimates) if e.is_keyframe]

    @property
    def tracked(self) -> list[bool]:
        """Per pose, whether tracking gave it (:data:`TRACKED_OUTCOMES`): the frames a stage may re-place."""
        return [e.outcome in TRACKED_OUTCOMES for e in self.estimates]

    @property
    def keyframe_points(self) -> dict[int, KeyframePoints]:
        """Each keyframe's points by frame index."""
        return {kf.index: kf.points for kf in self.keyframes}

    @property
    def loop_closed(self) -> Trajectory | None:
        """The loop-closed trajectory, None without loop closing."""
        return None if self.loops is None else self.loops.trajectory

    @property
    def loop_summary(self) -> LoopClosureSummary | None:
        """What loop closing found (``report.json`` keys), None without it."""
        return None if self.loops is None else self.loops.summary()

    def map_points(self) -> MapPoints:
        """The map (``points.ply``): the keyframes' points at :attr:`map_poses` (:func:`keyframe_map`)."""
        return keyframe_map(self.pinhole, self.keyframes, self.map_poses)

    def with_refined_keyframes(self, inverse_depths: Mapping[int, F64], covariances: Mapping[int, F64] | None,
                               source: str, **changes: Any) -> "OdometryResult":
        """A copy whose keyframes take ``inverse_depths`` and whose pose covariances take
        ``covariances`` (where given; their source then ``source``), with ``changes`` besides."""
        keyframes = tuple(dataclasses.replace(kf, points=dataclasses.replace(
            kf.points, inverse_depth=inverse_depths[kf.index])) if kf.index in inverse_depths else kf
            for kf in self.keyframes)
        cov = self.covariances
        if cov is not None and covariances is not None:
            merged = {int(i): P for i, P in zip(cov.frame_index, cov.covariance)}
            merged.update({int(i): cov.inflation * P for i, P in covariances.items()})
            stamp = {e.index: e.timestamp for e in self.estimates}
            rows = [(kf.index, merged[kf.index]) for kf in keyframes if kf.index in merged]
            cov = KeyframeCovariances(np.array([i for i, _ in rows], dtype=np.int64),
                                      np.array([stamp[i] for i, _ in rows]),
                                      np.array([P for _, P in rows]).reshape(-1, 6, 6), source, cov.inflation)
        return dataclasses.replace(self, keyframes=keyframes, covariances=cov, **changes)


def odometry_covariances(estimates: Sequence[FrameEstimate], keyframes: list[int]) -> list[F64 | None]:
    """Per pair of consecutive keyframes (positions in ``estimates``), the covariance of their
    relative pose: the tracker's covariance of the later keyframe when it was tracked against the
    earlier one (:attr:`FrameEstimate.keyframe_index`), else None.

    In window mode the keyframe poses are refined jointly after tracking, so the tracker's
    covariance is an upper bound of the relative pose's; it is the same photometric model as the
    loops' (:func:`gtvo.loops.direct_refinement.refine_loop`), which is what keeps the two kinds of
    edge on one scale.
    """
    kfs = sorted(set(int(k) for k in keyframes))
    out: list[F64 | None] = []
    for a, b in zip(kfs[:-1], kfs[1:]):
        e = estimates[b]
        ok = (e.tracking is not None and e.tracking.success and not e.reinitialised
              and e.keyframe_index == estimates[a].index and np.all(np.isfinite(e.tracking.covariance)))
        out.append(np.array(e.tracking.covariance, dtype=float) if ok else None)
    return out
