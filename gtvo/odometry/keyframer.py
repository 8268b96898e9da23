"""The keyframer: the odometry's keyframes and their link to the sliding window.

:class:`Keyframer` owns the keyframes (DSO's ``FullSystemMakeKeyframe`` and the window's side of
``FullSystemOptimize`` in one place): it makes a keyframe from a frame (its points with depths,
:mod:`gtvo.odometry.keyframe_points`; its tracker), and in window mode adds it to the
:class:`gtvo.window.SlidingWindowOptimizer`, optimises the window on the schedule of
:class:`gtvo.odometry.window_schedule.WindowSchedule`, writes the optimised poses and depths back
to its keyframes and has the history re-express the frames tracked against them. When the window
releases the rig offset's ``delta_x``, the window keyframes' depths are searched again against the
corrected right image. The rig offset itself lives in the window (``window.rig``).

The window is a :class:`gtvo.odometry.window_port.WindowPort`: in this process or in a worker
process beside the front end (``window.parallel``; with ``auto`` the schedule moves it there when
keyframes come often enough for it to pay), the keyframer drives both the same way. A
keyframe joins; the updates that are due come back and are written to the keyframes; a parallel
window's update is older than the front end's newest keyframes, which move with the update's newest
keyframe (in this process every update is due at once and that move is none).
"""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.photometric import GradientImage
from gtvo.config import OdometryConfig
from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.core.timing import stage
from gtvo.datasets.sequence import Frame
from gtvo.frontend import KeyframePoints
from gtvo.frontend.keyframes import needs_keyframe
from gtvo.frontend.tracking import TrackingKeyframe, TrackingResult, frame_pyramid
from gtvo.odometry.estimates import Keyframe, TooFewPoints, rigid_pose
from gtvo.odometry.history import FrameHistory
from gtvo.odometry.keyframe_points import frame_points
from gtvo.odometry.window_link import KeyframeForWindow, WindowUpdate
from gtvo.odometry.window_port import WindowPort, open_window
from gtvo.odometry.window_schedule import WindowSchedule
from gtvo.window import WindowResult
from gtvo.window.rig import RigOffset
from gtvo.window.imu import ImuWindow
from gtvo.window.wheel import WheelCalibration


class Keyframer:
    """Makes keyframes and keeps the window (module docstring).

    Args:
        camera: a :class:`StereoCamera` for stereo input, a :class:`PinholeCamera` for RGB-D.
        config: the run's settings.
        history: the run's frames (the keyframer re-expresses their poses when the window moves).
        wheel: the wheel odometry's calibration, which the window estimates (LM backend; with the
            fixed-lag backend it stays at its prior and only carries blind frames), or None.

    Attributes:
        keyframes: every keyframe made so far (window mode: with the last optimised pose and depths).
        window: the sliding window's port (window mode), else None: a
            :class:`gtvo.odometry.window_port.LocalWindow`, or with ``window.parallel`` the
            :class:`gtvo.odometry.window_worker.WindowWorker` that runs it beside the front end.
        window_results: one :class:`gtvo.window.WindowResult` per window optimisation.
        schedule: when the window is optimised.
        candidate: the last good frame with its left image, which the next frame may promote to a
            keyframe when it cannot be tracked against the latest one (None: no candidate).
    """

    def __init__(self, camera: StereoCamera | PinholeCamera, config: OdometryConfig, history: FrameHistory,
                 wheel: WheelCalibration | None = None, imu: ImuWindow | None = None) -> None:
        self.camera = camera
        self.pinhole = camera.left if isinstance(camera, StereoCamera) else camera
        self.config = config
        self.history = history
        self.keyframes: list[Keyframe] = []
        #: the window's port (window mode, :func:`gtvo.odometry.window_port.open_window`); None in track mode
        self.window: WindowPort | None = open_window(camera, config, wheel, imu) if config.mode == "window" else None
        self.window_results: list[WindowResult] = []
        self.schedule = WindowSchedule(config.window, config.photometric, self.pinhole)
        self.candidate: tuple[Frame, NDArray[np.float32]] | None = None
        self._by_index: dict[int, Keyframe] = {}
        # keyframe index -> per point, the most other keyframes a window optimisation compared it with
        self._observed: dict[int, NDArray[np.int64]] = {}

    @property
    def rig(self) -> RigOffset | None:
        """The rig offset the window estimates (its one owner; a parallel window: the worker's, as of
        its last update handed out), None when not estimated."""
        return None if self.window is None else self.window.rig

    def right_brightness(self) -> tuple[float, float] | None:
        """The right camera's brightness ``(a, b)`` relative to the left one from the newest window
        keyframe (a parallel window: as of its last applied update); None without one."""
        return None if self.window is None else self.window.right_brightness()

    def keyframe(self, index: int) -> Keyframe | None:
        """The keyframe made from frame ``index``, None when that frame is not a keyframe."""
        return self._by_index.get(index)

    def window_keyframes(self) -> list[Keyframe]:
        """The keyframes of the window (as of its last update handed out), oldest first; empty in
        track mode."""
        if self.window is None:
            return []
        return [kf for kf in (self._by_index.get(i) for i in self.window.keyframe_indices()) if kf is not None]

    def observed(self, index: int) -> NDArray[np.int64] | None:
        """Per point of keyframe ``index``: the most other keyframes one window optimisation compared
        it with; None when no optimisation included the keyframe."""
        return self._observed.get(index)

    def world_points(self, kf: Keyframe, T_world_cam: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """``kf``'s points in the world frame (N, 3) at its current pose and depths (or at the 4x4
        ``T_world_cam``), unfiltered: a point with a non-positive inverse depth is mirrored or at
        infinity (:meth:`gtvo.odometry.VisualOdometry.map_points` filters)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            X = self.pinhole.backproject_inverse_depth(kf.points.pixels, kf.points.inverse_depth)
        T = kf.T_world_cam.matrix() if T_world_cam is None else np.asarray(T_world_cam, dtype=float)
        return X @ T[:3, :3].T + T[:3, 3]

    def point_cloud(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Every keyframe's points in the world frame (N, 3) and their intensities (N,), unfiltered."""
        if not self.keyframes:
            return np.zeros((0, 3)), np.zeros(0)
        return (np.concatenate([self.world_points(kf) for kf in self.keyframes]),
                np.concatenate([kf.points.intensity for kf in self.keyframes]))

    def wants(self, kf: Keyframe, result: TrackingResult) -> bool:
        """The keyframe rule (:func:`gtvo.frontend.keyframes.needs_keyframe`): does a frame tracked
        against ``kf`` with ``result`` become a keyframe?"""
        return needs_keyframe(self.pinhole, kf.points, result, self.config.keyframes)

    def make(self, frame: Frame, left: NDArray[np.float32], T_world_cam: gtsam.Pose3,
             tracked: tuple[int, NDArray[np.float64]] | None = None,
             pyramid: list[GradientImage] | None = None) -> Keyframe:
        """Make ``frame`` a keyframe at ``T_world_cam``; in window mode, add it to the window and
        optimise on schedule (``tracked``: the keyframe it was tracked against and its affine relative
        to it; ``pyramid``: the frame's pyramid from its tracking, shared with the keyframe's tracker
        and the window instead of being computed again).

        Raises:
            TooFewPoints: the frame has fewer than ``tracking.min_valid_points`` points with a depth.
        """
        right = frame.right if isinstance(self.camera, StereoCamera) else None  # float32 gray (Frame)
        pts = frame_points(frame, left, right, self.camera, self.config, self.rig)
        if len(pts) < self.config.tracking.min_valid_points:
            need = self.config.tracking.min_valid_points
            raise TooFewPoints(f"frame {frame.index}: only {len(pts)} points with a valid depth, fewer than "
                               f"tracking.min_valid_points = {need}; "
                               + ("that setting asks for more than frontend.points_per_keyframe = "
                                  f"{self.config.frontend.points_per_keyframe} selects"
                                  if need > self.config.frontend.points_per_keyframe
                                  else "the images may be blank or the stereo calibration wrong"))
        if self.window is not None:
            if pyramid is None:  # one pyramid for the window keyframe's image and the tracker (no tracking made it)
                with stage("keyframe_setup"):
                    pyramid = frame_pyramid(left, self.config.tracking.levels, self.config.photometric.clip_range)
            T_world_cam, pts = self._join_window(frame, right, T_world_cam, pts, tracked, pyramid)
        with stage("keyframe_setup"):  # the new keyframe's tracker: its pyramid with gradients (or the frame's)
            tracker = TrackingKeyframe(self.pinhole, left, pts.pixels, pts.inverse_depth, pts.variance, (0.0, 0.0),
                                       self.config.tracking, pyramid=pyramid, photometric=self.config.photometric)
        image = left if self.config.flow_fallback is not None else None  # converted only if the fallback runs
        kf = Keyframe(frame.index, rigid_pose(T_world_cam.matrix()), pts, tracker, image)
        if self.keyframes:
            self.keyframes[-1].tracker = self.keyframes[-1].image = None
        self.keyframes.append(kf)
        self._by_index[kf.index] = kf
        if self.window is not None:
            self._re_express()
        return kf

    def try_make(self, frame: Frame, left: NDArray[np.float32], T_world_cam: gtsam.Pose3,
                 tracked: tuple[int, NDArray[np.float64]] | None = None,
                 pyramid: list[GradientImage] | None = None) -> Keyframe | None:
        """:meth:`make`, or None (nothing changed) when the frame has too few points."""
        try:
            return self.make(frame, left, T_world_cam, tracked, pyramid)
        except TooFewPoints:
            return None

    def finish(self) -> None:
        """Optimise the keyframes that joined the window since its last optimisation, apply every
        update not applied yet (a parallel window: the front end waits for the worker) and
        re-express their frames; nothing to do in track mode or when nothing is waiting."""
        if self.window is None:
            return
        if self.schedule.waiting:
            self.schedule.waiting = 0
            self.window.optimize()
        updates = self.window.finish()
        for update in updates:
            self._apply(update)
        if updates:
            self._re_express()

    def close(self) -> None:
        """Release the window's machine (``window.parallel``: end its worker process)."""
        if self.window is not None:
            self.window.close()

    # -- the window ----------------------------------------------------------------------------------
    def _join_window(self, frame: Frame, right_image: NDArray[np.float32] | None, T_world_cam: gtsam.Pose3,
                     pts: KeyframePoints,
                     tracked: tuple[int, NDArray[np.float64]] | None,
                     pyramid: list[GradientImage]) -> tuple[gtsam.Pose3, KeyframePoints]:
        """Add a new keyframe to the window and optimise on schedule; returns its pose and points
        (optimised when its own update was due now; else moved by the updates applied now)."""
        assert self.window is not None
        timestamp = float(frame.timestamp) if np.isfinite(frame.timestamp) else None
        last = self.keyframes[-1] if self.keyframes else None
        anchor = None if last is None else (last.index, last.T_world_cam.matrix())
        request = KeyframeForWindow(frame.index, timestamp, T_world_cam, pts, tracked, pyramid[0], right_image, anchor)
        self.schedule.waiting += 1
        follows = last is not None and self.history.latest_other_than(frame.index) == last.index
        wait = last is not None and self.schedule.may_wait(tracked is not None, follows, last.T_world_cam,
                                                            T_world_cam, pts)
        if not wait:
            self.schedule.waiting = 0
        self.window.join(request, optimize=not wait)
        # the next frames may track against its stereo depths, or it waits for its window now
        lag = last is not None and self.schedule.may_go_unrefined(tracked is not None, follows, last.T_world_cam,
                                                                   T_world_cam, pts)
        self.schedule.note_keyframe(lag)
        updates = self.window.due(now=not lag)
        for update in updates:
            T_world_cam = self._apply(update, T_world_cam)
        if self.schedule.moves_to_worker():  # window.parallel: auto, and keyframes come often enough
            self.window = self.window.on_second_core()
        new = updates[-1].members[-1] if updates else None
        if new is not None and new.index == frame.index:  # its own optimisation: its pose and depths
            return new.pose, dataclasses.replace(pts, inverse_depth=new.inverse_depth.copy())
        return T_world_cam, pts

    def _apply(self, update: WindowUpdate, T_new: gtsam.Pose3 | None = None) -> gtsam.Pose3 | None:
        """Write a window update back: the frames tracked against keyframes whose depths changed
        scale (the rig offset's release), the results, the observation counts, the keyframes'
        poses and depths. An update older than the front end's newest keyframes (a parallel
        window's): those (and ``T_new``, the pose of the keyframe being made) move with the
        update's newest keyframe, as the worker places them. Returns ``T_new`` so moved."""
        if update.tracked_scales:
            self.history.rescale_tracked(update.tracked_scales, self._by_index)
        self.window_results.append(update.result)
        for index, n in update.observed.items():
            prev = self._observed.get(index)
            self._observed[index] = n if prev is None or len(prev) != len(n) else np.maximum(prev, n)
        newest = update.members[-1]
        later = [kf for kf in self.keyframes if kf.index > newest.index]  # made since the update's window
        correction = None
        if (later or T_new is not None) and newest.index in self._by_index:
            correction = newest.pose.compose(self._by_index[newest.index].T_world_cam.inverse())
        for w in update.members:
            old = self._by_index.get(w.index)
            if old is not None:
                old.T_world_cam = w.pose
                old.points = dataclasses.replace(old.points, inverse_depth=w.inverse_depth.copy())
        if correction is not None:
            for kf in later:
                kf.T_world_cam = correction.compose(kf.T_world_cam)
            if T_new is not None:
                T_new = correction.compose(T_new)
        return T_new

    def _re_express(self) -> None:
        """Have the history re-express the frames of the window's keyframes at their new poses."""
        assert self.window is not None
        indices = self.window.keyframe_indices()
        if indices:
            self.history.re_express(self._by_index, since=indices[0])
