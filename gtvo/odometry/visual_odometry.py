"""The visual-odometry driver: frames in, poses out.

:class:`VisualOdometry` is fed one :class:`gtvo.datasets.sequence.Frame` at a time (a user who
imports gtvo as a backend does exactly this) and returns a :class:`FrameEstimate` per frame. It is
composed of parts that each own their state, in their own files:

* :class:`gtvo.odometry.history.FrameHistory`: every frame's estimate so far;
* :class:`gtvo.odometry.motion.MotionModel`: the guess of the next pose (constant velocity, or the
  constant-acceleration Kalman filter), learning from every recorded frame;
* :class:`gtvo.odometry.frame_tracking.FrameTracker`: tracking against the latest keyframe from
  several guesses, with the optical-flow fallback;
* :class:`gtvo.odometry.checks.FrameChecks`: whether a frame is *frozen* (its image repeats the
  previous one's while the rig moves) or a tracked frame *suspect*;
* :class:`gtvo.odometry.keyframer.Keyframer`: the keyframes (points with stereo or RGB-D depths)
  and their link to the sliding window (schedule, write-back, the rig offset's window).

:meth:`VisualOdometry._process` reads as the algorithm's steps (docs/architecture.md, "The
odometry loop"); the residual math is in :mod:`factors`, the window in :mod:`gtvo.window`.
"""

from __future__ import annotations

import time
from contextlib import nullcontext
from dataclasses import dataclass
from typing import Mapping

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.photometric import GradientImage
from gtvo.config import OdometryConfig
from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.core.map_points import MapPoints
from gtvo.core.timing import StageClock
from gtvo.datasets.sequence import Frame
from gtvo.datasets.imu import ImuMeasurements
from gtvo.datasets.wheel import WheelOdometry
from gtvo.errors import InputError
from gtvo.evaluation.trajectory import Trajectory
from gtvo.odometry.blas import single_threaded_blas
from gtvo.odometry.checks import FrameChecks
from gtvo.odometry.estimates import FrameEstimate, FrameOutcome, Keyframe, TooFewPoints, rigid_pose
from gtvo.odometry.frame_tracking import FrameTracker, Track
from gtvo.odometry.history import FrameHistory
from gtvo.odometry.keyframer import Keyframer
from gtvo.odometry.motion import MotionModel
from gtvo.odometry.result import MapKeyframe, keyframe_map
from gtvo.odometry.view import OdometryView
from gtvo.odometry.wheel import wheel_calibration
from gtvo.odometry.window_port import WindowPort
from gtvo.window.imu import ImuWindow, imu_window_settings


@dataclass(frozen=True)
class Outcome:
    """What the driver decided about one frame, recorded as its :class:`FrameEstimate`.

    Attributes:
        kind: how the frame was handled.
        T_world_cam: its pose.
        track: its tracking against the latest keyframe (None: the first frame).
        T_keyframe_frame: a frame that is not a keyframe: its pose relative to its keyframe.
        reason: why it was lost, re-initialised or suspect.
        candidate: whether the next frame may promote it to a keyframe (not when it is lost or
            just failed to become one; a suspect frame leaves the candidate as it was).
    """

    kind: FrameOutcome
    T_world_cam: gtsam.Pose3
    track: Track | None = None
    T_keyframe_frame: gtsam.Pose3 | None = None
    reason: str = ""
    candidate: bool = True


class VisualOdometry:
    """Frame-to-keyframe direct stereo (or RGB-D) odometry, with a sliding window in window mode.

    Args:
        camera: a :class:`StereoCamera` for stereo input, a :class:`PinholeCamera` for RGB-D.
        config: settings (defaults suit KITTI-like and indoor data alike).

    Attributes:
        history, motion, tracker, checks, keyframer: the parts (module docstring).
        estimates: one :class:`FrameEstimate` per processed frame (``history.estimates``).
        keyframes: every keyframe made so far (``keyframer.keyframes``).
        window: the sliding window's port (:class:`gtvo.odometry.window_port.WindowPort`; window
            mode; the keyframer's, which ``window.parallel: auto`` may move to a worker during the
            run), else None: the window in this process, or with ``window.parallel`` in a worker
            process (its state as of its last update handed out; call :meth:`close`, or use the
            odometry as a context manager, to end the worker early). Its ``rig`` is the rig
            offset's estimate when the window calibrates the rig.
        window_results: one :class:`gtvo.window.WindowResult` per window optimisation.
        failures: frames whose tracking failed (re-initialised or lost).
        lost_frames: frames whose tracking failed and that had too few points to become a
            keyframe, placed by the motion model's guess (``LOST``; not the ``WHEEL_CARRIED`` ones,
            placed by the wheels); also counted in ``failures``.
        wheel: the wheel odometry's calibration (:class:`gtvo.window.wheel.WheelCalibration`; the
            window's in window mode), None without wheel odometry.
        clock: the :class:`gtvo.core.timing.StageClock` every :meth:`process` charges (where the
            frames' time went); set it to None to run untimed.

    Example::

        vo = VisualOdometry(seq.camera)
        for frame in seq:
            est = vo.process(frame)
        vo.finish()
        traj = vo.trajectory()
    """

    def __init__(self, camera: StereoCamera | PinholeCamera, config: OdometryConfig | None = None,
                 wheel_odometry: WheelOdometry | None = None, imu: ImuMeasurements | None = None) -> None:
        self.camera = camera
        self.pinhole = camera.left if isinstance(camera, StereoCamera) else camera
        self.config = config or OdometryConfig()
        self.wheel = None if wheel_odometry is None else wheel_calibration(self.config.wheel, wheel_odometry)
        self.history = FrameHistory()
        self.motion = MotionModel(self.config.motion_model, self.history)
        self.tracker = FrameTracker(self.config, self.pinhole)
        self.checks = FrameChecks(self.config.frame_checks, self.pinhole, self.history)
        #: the IMU in the window (gtvo.window.imu.ImuWindow; None: no IMU, or not in window mode; docs/imu.md)
        self.imu = None if imu is None or self.config.mode != "window" else ImuWindow(imu, imu_window_settings(
            self.config.imu))
        self.keyframer = Keyframer(camera, self.config, self.history, self.wheel, self.imu)
        self.estimates = self.history.estimates
        self.keyframes = self.keyframer.keyframes
        self.window_results = self.keyframer.window_results
        self.failures = 0
        self.lost_frames = 0
        self.clock: StageClock | None = StageClock()
        self._last: tuple[Track | None, Keyframe | None] = (None, None)  # the latest frame's, for view()

    # -- public ---------------------------------------------------------------------------------
    def process(self, frame: Frame) -> FrameEstimate:
        """Estimate the pose of the next frame (frames must come in time order).

        BLAS runs single-threaded inside (threadpoolctl): the tracker's and the window's many
        small matrix products were up to 300x slower multithreaded on a busy 2-core machine.
        """
        with self.clock.activate("other") if self.clock is not None else nullcontext(), single_threaded_blas():
            return self._process(frame)  # time outside the named stages: "other"

    def finish(self) -> None:
        """Optimise the keyframes that joined the window since its last optimisation
        (``WindowConfig.optimize_every`` > 1) and re-express their frames; nothing to do in track
        mode or when none is waiting. Call it after the last frame (``gtvo.run`` does); frames may
        still follow (the next keyframe joins the window as usual)."""
        with self.clock.activate("other") if self.clock is not None else nullcontext(), single_threaded_blas():
            self.keyframer.finish()

    @property
    def window(self) -> WindowPort | None:
        """The sliding window's port (class docstring), None in track mode."""
        return self.keyframer.window

    def close(self) -> None:
        """End the window's worker process (``window.parallel``; it also ends when this object is
        collected or the process exits); nothing to do otherwise. The estimates stay readable."""
        self.keyframer.close()

    def __enter__(self) -> "VisualOdometry":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def trajectory(self, name: str = "gtvo") -> Trajectory:
        """The estimated left-camera trajectory so far (every frame; window mode: call :meth:`finish`
        after the last frame so that the last keyframes are optimised too)."""
        if not self.estimates:
            raise InputError("no frame has been processed yet")
        return Trajectory(np.array([e.timestamp for e in self.estimates]),
                          np.stack([e.T_world_cam for e in self.estimates]), name=name)

    def map_points(self, keyframe_poses: Mapping[int, NDArray[np.float64]] | None = None) -> MapPoints:
        """The keyframe points whose depth the run constrains, in the world frame (what ``points.ply``
        holds): inverse depth positive, relative depth sigma bounded and, for keyframes that a window
        optimisation included, seen from enough keyframes in one (:mod:`gtvo.core.map_points`); the
        rest counted.

        ``keyframe_poses``: ``{keyframe index: 4x4 T_world_cam}`` to place keyframes elsewhere than
        at their odometry poses (e.g. after loop closing); a keyframe missing from it keeps its own.
        """
        return keyframe_map(self.pinhole, [MapKeyframe(kf.index, kf.T_world_cam.matrix(), kf.points,
                                                        self.keyframer.observed(kf.index)) for kf in self.keyframes],
                            keyframe_poses)

    def covariance(self, keyframe: int | Keyframe, inflation: float = 1.0) -> NDArray[np.float64] | None:
        """The 6x6 pose covariance of a keyframe (its frame index, or the :class:`Keyframe`) from the
        last window optimisation it was part of: GTSAM's tangent order ``[rotation, translation]``,
        right perturbation ``T = T_hat * Exp(xi)`` (``xi`` in the keyframe's own camera frame),
        relative to the world frame fixed by the first keyframe (docs/window.md, "Pose covariances").

        None when no covariance was computed for it: track mode, ``WindowConfig.covariances=False``,
        or a keyframe no window optimisation has included yet (with ``window.optimize_every`` > 1 the
        newest keyframe may wait for the next optimisation, or for :meth:`finish`). Raises
        :class:`InputError` for a frame index that is not a keyframe.

        ``inflation`` multiplies the window's covariance: the window's marginals are optimistic
        (measured on noisy synthetic sequences: mean NEES 4-8x the consistent value, docs/benchmarks.md,
        "Covariance honesty (NEES)"); 1.0 returns the window's own.
        """
        if not (np.isfinite(inflation) and inflation > 0):
            raise InputError(f"covariance inflation must be positive, got {inflation!r}")
        index = keyframe.index if isinstance(keyframe, Keyframe) else int(keyframe)
        if self.keyframer.keyframe(index) is None:
            raise InputError(f"frame {index} is not a keyframe of this run")
        if self.window is None:
            return None
        P = self.window.covariances.get(index)
        return None if P is None else float(inflation) * P

    def view(self) -> OdometryView:
        """What an observer may read after the latest frame (:class:`gtvo.odometry.view.OdometryView`):
        copies, so that nothing an observer does changes the odometry."""
        track, kf = self._last
        return OdometryView.after(self.history, self.keyframer, self.config.photometric, track, kf)

    # -- the algorithm --------------------------------------------------------------------------
    def _process(self, frame: Frame) -> FrameEstimate:
        t0 = time.perf_counter()
        if self.estimates and frame.timestamp <= self.estimates[-1].timestamp:
            raise InputError(f"frame {frame.index}: timestamp {frame.timestamp} is not after the previous frame's")
        left = frame.left  # float32 gray, converted once where the frame was read (Frame)
        if not self.keyframes:                                            # 1. the first frame starts the map
            try:
                kf = self.keyframer.make(frame, left, gtsam.Pose3())
            except TooFewPoints as exc:  # nothing can start from the first frame
                raise InputError(str(exc)) from None
            return self._record(frame, left, Outcome(FrameOutcome.KEYFRAME, kf.T_world_cam), t0)
        T_pred = self._imu_pose(frame) or self._gyro_turned(frame, self.motion.predict(frame.timestamp))  # 2. predict
        #    (the IMU's, with one; before its initialisation the motion model's turned by the gyro; after a freeze
        #    the wheels)
        T_wheel = self._wheel_pose(frame)
        if (why := self.checks.frozen(frame, left, self.keyframes[-1], T_pred if T_wheel is None else T_wheel,
                                      T_wheel is not None)) is not None:  # 2b. a frozen camera: a guess, untracked
            T_guess, kf = T_pred if T_wheel is None else T_wheel, self.keyframes[-1]
            return self._record(frame, left, Outcome(FrameOutcome.FROZEN, T_guess, None,
                                                     kf.T_world_cam.between(T_guess), why), t0)
        if T_wheel is not None and self.estimates[-1].outcome is FrameOutcome.FROZEN:
            T_pred = T_wheel  # after a freeze the wheels, which measured the gap, are the better guess
        pyramid = self.tracker.pyramid(left, self.keyframes[-1])
        kf, track, T_pred, last = self._track(frame, left, pyramid, T_pred)  # 3. track (guesses, promotion, flow)
        if not track.result.success:                                      # 4. re-initialise, or the frame is lost
            return self._record(frame, left, self._reinitialise(frame, left, kf, track, T_pred, pyramid), t0)
        T_world = kf.T_world_cam.compose(track.result.T_keyframe_frame)
        if (why := self.checks.suspect(frame, kf, last, T_pred, T_world)) is not None:  # 5. suspect: the prediction
            return self._record(frame, left, Outcome(FrameOutcome.SUSPECT, T_pred, track,
                                                     kf.T_world_cam.between(T_pred), why), t0)
        plain = FrameOutcome.TRACKED if track.flow_reason is None else FrameOutcome.RECOVERED
        if self.keyframer.wants(kf, track.result):                        # 6. keyframe rule, window schedule
            new_kf = self.keyframer.try_make(frame, left, T_world, (kf.index, track.result.affine), pyramid)
            if new_kf is not None:
                return self._record(frame, left, Outcome(FrameOutcome.KEYFRAME, new_kf.T_world_cam, track), t0)
            return self._record(frame, left, Outcome(plain, T_world, track, track.result.T_keyframe_frame,
                                                     candidate=False), t0)
        return self._record(frame, left, Outcome(plain, T_world, track, track.result.T_keyframe_frame), t0)  # 7.

    def _track(self, frame: Frame, left: NDArray[np.float32], pyramid: list[GradientImage], T_pred: gtsam.Pose3
               ) -> tuple[Keyframe, Track, gtsam.Pose3, gtsam.Pose3]:
        """Track the frame (``left``, its ``pyramid``) against the latest keyframe. When that fails,
        or the keyframe's points have left the view, the previous frame (the candidate, whose pose
        is tracked) becomes the keyframe and the frame is tracked against it. Returns the keyframe,
        the tracking, the prediction and the last good frame's pose (both moved along with a
        promoted keyframe)."""
        kf = self.keyframes[-1]
        last = rigid_pose(self.history.good(1)[0].T_world_cam)
        track = self.tracker.track(kf, pyramid, T_pred, last, left, self.history.affine_guess(kf.index),
                                   self.history.last_rms())
        lost_view = track.result.n_valid < self.config.keyframes.min_visible * len(kf.points)
        candidate = self.keyframer.candidate
        if (track.result.success and not lost_view) or candidate is None or candidate[0].index == kf.index:
            return kf, track, T_pred, last
        prev = self.history.good(1)[0]
        tracked = None
        if prev.tracking is not None and self.keyframer.keyframe(prev.keyframe_index) is not None:
            tracked = (prev.keyframe_index, prev.tracking.affine)
        promoted = self.keyframer.try_make(candidate[0], candidate[1], last, tracked)
        if promoted is None:  # keep tracking against the current keyframe; do not retry that frame
            self.keyframer.candidate = None
            return kf, track, T_pred, last
        self.history.mark_last_good_as_keyframe()
        # the window may have moved the new keyframe: carry the guesses along with it
        correction = promoted.T_world_cam.compose(last.inverse())
        T_pred, last = correction.compose(T_pred), promoted.T_world_cam
        track = self.tracker.track(promoted, pyramid, T_pred, last, left, self.history.affine_guess(promoted.index),
                                   self.history.last_rms())
        return promoted, track, T_pred, last

    def _reinitialise(self, frame: Frame, left: NDArray[np.float32], kf: Keyframe, track: Track,
                      T_pred: gtsam.Pose3, pyramid: list[GradientImage]) -> Outcome:
        """Tracking failed: the frame becomes a keyframe at the motion model's prediction, or, with
        too few points for that (a blank or covered view), it is lost and keeps the prediction.
        With wheel odometry that covers the step from the last good frame, the calibrated wheel
        motion places it instead (a lost frame is then ``WHEEL_CARRIED``); with an initialised IMU
        that covers it, the IMU's prediction from the latest keyframe (``IMU_CARRIED``)."""
        self.failures += 1
        self.checks.not_checked()
        T_imu = self._imu_pose(frame)
        T_wheel = self._wheel_pose(frame) if T_imu is None else None
        T_place = T_imu or T_wheel or T_pred
        by_wheel = ("" if T_wheel is None else ", placed by the calibrated wheel odometry") + (
            "" if T_imu is None else ", placed by the IMU")
        new_kf = self.keyframer.try_make(frame, left, T_place, pyramid=pyramid)
        if new_kf is None:
            carried = (FrameOutcome.IMU_CARRIED if T_imu is not None else
                       FrameOutcome.WHEEL_CARRIED if T_wheel is not None else FrameOutcome.LOST)
            if carried is FrameOutcome.LOST:  # a carried frame is placed by a measurement: not lost
                self.lost_frames += 1
            return Outcome(carried, T_place, track,
                           kf.T_world_cam.between(T_place),
                           f"tracking failed ({track.result.reason}); too few points with a depth to re-initialise"
                           + by_wheel)
        return Outcome(FrameOutcome.REINITIALISED, new_kf.T_world_cam, track,
                       reason=f"tracking failed ({track.result.reason}){by_wheel}")

    def _imu_pose(self, frame: Frame) -> gtsam.Pose3 | None:
        """The frame's pose predicted by the IMU from the latest keyframe with a velocity and a bias
        (:meth:`gtvo.window.imu.ImuWindow.predict_at`); None without an initialised IMU or when its
        readings do not cover the step."""
        return None if self.imu is None else self.imu.predict_at(float(frame.timestamp))

    def _gyro_turned(self, frame: Frame, T_motion: gtsam.Pose3) -> gtsam.Pose3:
        """``T_motion`` (the motion model's guess) with its rotation the gyro's from the last good frame
        (:meth:`gtvo.window.imu.ImuWindow.camera_rotation`: a turn the images have not seen yet is
        measured); ``T_motion`` itself without an IMU or when the readings do not cover the step."""
        if self.imu is None:
            return T_motion
        last = self.history.good(1)[0]
        R = self.imu.camera_rotation(last.timestamp, float(frame.timestamp))
        if R is None:
            return T_motion
        return gtsam.Pose3(rigid_pose(last.T_world_cam).rotation().compose(R), T_motion.translation())

    def _wheel_pose(self, frame: Frame) -> gtsam.Pose3 | None:
        """The frame's pose carried from the last good frame by the calibrated wheel motion; None
        without wheel odometry or when it does not cover the step."""
        if self.wheel is None:
            return None
        last = self.history.good(1)[0]
        return self.wheel.predict(rigid_pose(last.T_world_cam), last.timestamp, float(frame.timestamp))

    def _record(self, frame: Frame, left: NDArray[np.float32], outcome: Outcome, t0: float) -> FrameEstimate:
        """Record the frame's estimate; the motion model learns from it and it becomes the keyframe
        candidate (unless it is suspect, lost or just failed to become a keyframe)."""
        kind, result = outcome.kind, None if outcome.track is None else outcome.track.result
        tracked = result is not None and kind is not FrameOutcome.REINITIALISED
        kf_index = self.keyframes[-1].index if tracked or kind is FrameOutcome.FROZEN else frame.index
        if tracked and kind is FrameOutcome.KEYFRAME:  # tracked against the keyframe before this one
            kf_index = self.keyframes[-2].index
        flow_reason = outcome.track.flow_reason if outcome.track is not None else None
        flow = tracked and kind not in (FrameOutcome.LOST, FrameOutcome.WHEEL_CARRIED,
                                        FrameOutcome.IMU_CARRIED) and flow_reason is not None
        reason = outcome.reason or (flow_reason or "" if flow else "")
        est = FrameEstimate(frame.index, float(frame.timestamp), outcome.T_world_cam.matrix(), kind, result,
                            time.perf_counter() - t0, kf_index, outcome.T_keyframe_frame, reason, flow)
        self.history.append(est)
        self._last = (outcome.track if tracked else None, self.keyframer.keyframe(kf_index))
        if not est.excluded:  # a suspect or frozen frame: not learnt from; the candidate stays the last good frame
            self.keyframer.candidate = (frame, left) if outcome.candidate and not est.lost else None
            self.motion.update(est)
        return est
