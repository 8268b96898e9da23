"""The visual-odometry driver: frames in, poses out.

:class:`VisualOdometry` is fed one :class:`gtvo.datasets.sequence.Frame` at a time (a user who imports
gtvo as a backend does exactly this) and returns a :class:`FrameEstimate` per frame. This module
is the loop; the front end's parts live in :mod:`gtvo.frontend` (tracker, point selection, stereo
depth, keyframe rule), the residual math in :mod:`factors`, the window in :mod:`gtvo.window`:

* the first frame becomes a keyframe: points selected in the left image
  (:func:`gtvo.frontend.select_points`) get inverse depths and variances from stereo
  (:func:`gtvo.frontend.init_keyframe_points`) or, for RGB-D, from the sensor's depth;
* every later frame is tracked against the latest keyframe (coarse to fine, hand-rolled or
  GTSAM solver), starting from a motion-model prediction (constant velocity, or the
  constant-acceleration Kalman filter when it is available and chosen);
* a new keyframe is made when the keyframe's points drift out of view, the motion relative to
  the keyframe grows large against the scene depth, or the brightness changes a lot (rule in
  :mod:`gtvo.frontend.keyframes`);
* a tracked frame whose image contradicts a motion model that has been right (a duplicated or
  out-of-order image, :mod:`gtvo.frontend.frame_checks`) is *suspect*: it keeps the predicted
  pose, makes no keyframe and is left out of the next prediction;
* when tracking fails, the frame is re-initialised from stereo at the predicted pose and the run
  goes on; a frame with too few points for that (a blank or covered view) is *lost*: it keeps the
  predicted pose and the next frames are tracked against the keyframe again; both are counted;
* with ``mode="window"`` every new keyframe joins a :class:`gtvo.window.SlidingWindowOptimizer`;
  after every ``window.optimize_every``-th keyframe (and at :meth:`VisualOdometry.finish`)
  the window's keyframe poses, affine brightness and inverse depths are optimised jointly, the
  optimised keyframes replace the tracked ones (later frames are tracked against them, with the
  optimised depths) and every frame's pose is re-expressed relative to its keyframe's optimised
  pose.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Mapping

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.core.timing import StageClock, stage, timed
from gtvo.errors import InputError
from gtvo.frontend import optical_flow_pose
from gtvo.core.image import to_float_gray
from gtvo.datasets.sequence import Frame
from gtvo.frontend.tracking import TrackingResult, frame_pyramid, track_gtsam, track_handrolled, track_with_guesses
from gtvo.evaluation.trajectory import Trajectory
from gtvo.config import OdometryConfig
from gtvo.frontend.frame_checks import FrameChecker, measure_step
from gtvo.frontend.keyframes import needs_keyframe
from gtvo.odometry.keyframe_making import KeyframeMaking, single_threaded_blas
from gtvo.odometry.estimates import TooFewPoints, rigid_pose
from gtvo.odometry.estimates import FrameEstimate, FrameOutcome, Keyframe
from gtvo.window import SlidingWindowOptimizer, WindowResult
from gtvo.core.map_points import MapPoints, constrained_mask

class VisualOdometry(KeyframeMaking):
    """Frame-to-keyframe direct stereo (or RGB-D) odometry.

    Args:
        camera: a :class:`StereoCamera` for stereo input, a :class:`PinholeCamera` for RGB-D.
        config: settings (defaults suit KITTI-like and indoor data alike).

    Attributes:
        estimates: one :class:`FrameEstimate` per processed frame.
        keyframes: every keyframe made so far (window mode: with the last optimised pose and depths).
        window: the :class:`gtvo.window.SlidingWindowOptimizer` (window mode), else None.
        window_results: one :class:`gtvo.window.WindowResult` per window optimisation.
        flow_recoveries: frames that failed from every motion-model guess and were tracked from
            the optical-flow guess (``config.flow_fallback``) instead of being lost.
        lost_frames: frames whose tracking failed and that had too few points to become a
            keyframe (:attr:`FrameEstimate.lost`); also counted in ``failures``.
        clock: the :class:`gtvo.core.timing.StageClock` every :meth:`process` charges (where the
            frames' time went, :attr:`stage_seconds`); set it to None to run untimed.

    Example::

        vo = VisualOdometry(seq.camera)
        for frame in seq:
            est = vo.process(frame)
        vo.finish()
        traj = vo.trajectory()
    """

    def __init__(self, camera: StereoCamera | PinholeCamera, config: OdometryConfig | None = None) -> None:
        self.camera = camera
        self.pinhole = camera.left if isinstance(camera, StereoCamera) else camera
        self.config = config or OdometryConfig()
        self.estimates: list[FrameEstimate] = []
        self.keyframes: list[Keyframe] = []
        self.failures = 0
        self.flow_recoveries = 0
        self.lost_frames = 0
        self.window_results: list[WindowResult] = []
        self.clock: StageClock | None = StageClock()
        self._keyframe_rule = self.config.keyframes
        self._previous: tuple[Frame, NDArray[np.float32]] | None = None
        self._checker = FrameChecker(self.config.frame_checks)
        self._flow_reason: str | None = None  # set by _track when the optical-flow guess tracked the frame
        self._kalman = None
        self._keyframe_by_index: dict[int, Keyframe] = {}
        self._window_affine: dict[int, NDArray[np.float64]] = {}  # keyframe index -> (a, b) in the window
        # keyframe index -> per point, the most other keyframes a window optimisation compared it with
        self._observed: dict[int, NDArray[np.int64]] = {}
        self._window_waiting = 0  # keyframes that joined the window since its last optimisation
        self.window: SlidingWindowOptimizer | None = None
        #: the stereo rig's offset ``(delta_x, delta_y)`` of the right image (px) as estimated so
        #: far (docs/window.md, "Rig calibration"), None when not estimated (RGB-D, track mode, the
        #: fixed-lag backend or ``window.rig_calibration=False``)
        self.rig_offset: NDArray[np.float64] | None = None
        #: the first frame's vertical-offset search (:func:`gtvo.frontend.rig_offset.estimate_vertical_offset`)
        self.rig_initial = None
        if self.config.mode == "window":
            baseline = camera.baseline if isinstance(camera, StereoCamera) else None
            wcfg = self.config.window
            rig = baseline is not None and wcfg.rig_calibration and wcfg.backend == "lm"
            self.rig_offset = np.zeros(2) if rig else None
            self.window = SlidingWindowOptimizer(self.pinhole, baseline, wcfg, rig_offset=self.rig_offset)
        if self.config.motion_model.model == "kalman":
            from gtvo.motion.model import ConstantAccelerationFilter  # noqa: PLC0415

            mm = self.config.motion_model
            self._kalman = ConstantAccelerationFilter(mm.kalman_noise, mm.kalman_initial_rate_sigmas)

    # -- public ---------------------------------------------------------------------------------
    def process(self, frame: Frame) -> FrameEstimate:
        """Estimate the pose of the next frame (frames must come in time order).

        BLAS runs single-threaded inside (threadpoolctl): the tracker's and the window's many
        small matrix products were up to 300x slower multithreaded on a busy 2-core machine.
        """
        if self.clock is None:
            with single_threaded_blas():
                return self._process(frame)
        with self.clock.activate("other"), single_threaded_blas():  # time outside the named stages: "other"
            return self._process(frame)

    @property
    def stage_seconds(self) -> dict[str, float]:
        """Seconds so far in each stage (:data:`gtvo.core.timing.FRAME_STAGES`, docs/evaluation.md): they
        add up to the time spent in :meth:`process` and :meth:`finish`. Empty when :attr:`clock` is None."""
        return {} if self.clock is None else self.clock.snapshot()

    def _process(self, frame: Frame) -> FrameEstimate:
        t0 = time.perf_counter()
        if self.estimates and frame.timestamp <= self.estimates[-1].timestamp:
            raise InputError(f"frame {frame.index}: timestamp {frame.timestamp} is not after the previous frame's")
        left = to_float_gray(frame.left, f"frame {frame.index} left image")
        if not self.keyframes:
            try:
                kf = self._make_keyframe(frame, left, gtsam.Pose3())
            except TooFewPoints as exc:  # nothing can start from the first frame
                raise InputError(str(exc)) from None
            return self._finish(frame, left, kf.T_world_cam, FrameOutcome.KEYFRAME, None, t0)

        kf = self.keyframes[-1]
        assert kf.tracker is not None  # the latest keyframe keeps its tracker
        T_pred = self._predict(frame.timestamp)
        last = rigid_pose(self._good_estimates(1)[0].T_world_cam)
        with stage("tracking", absorb=True):
            pyr = frame_pyramid(left, kf.tracker.levels, self.config.photometric.clip_range)
        result = self._track(kf, pyr, T_pred, last, left)
        lost_view = result.n_valid < self.config.keyframes.min_visible * len(kf.points)
        if (not result.success or lost_view) and self._previous is not None and self._previous[0].index != kf.index:
            # the view has moved on (or tracking failed): the previous frame, whose pose is
            # tracked, becomes the keyframe, and this frame is tracked against it
            prev_frame, prev_left = self._previous
            prev = self._good_estimates(1)[0]
            tracked = None
            if prev.tracking is not None and prev.keyframe_index in self._keyframe_by_index:
                tracked = (prev.keyframe_index, prev.tracking.affine)
            promoted = self._make_keyframe_if_possible(prev_frame, prev_left, last, tracked)
            if promoted is None:  # keep tracking against the current keyframe; do not retry that frame
                self._previous = None
            else:
                kf = promoted
                self._mark_last_as_keyframe()
                # the window may have moved the new keyframe: carry the guesses along with it
                correction = kf.T_world_cam.compose(last.inverse())
                T_pred, last = correction.compose(T_pred), kf.T_world_cam
                result = self._track(kf, pyr, T_pred, last, left)
        if not result.success:
            # re-initialise: this frame becomes a keyframe at the motion model's prediction
            self.failures += 1
            self._checker.not_checked()
            new_kf = self._make_keyframe_if_possible(frame, left, T_pred, pyramid=pyr)
            if new_kf is None:  # nothing to re-initialise from: the frame is lost
                self.lost_frames += 1
                return self._finish(frame, left, T_pred, FrameOutcome.LOST, result, t0,
                                    T_keyframe_frame=kf.T_world_cam.between(T_pred),
                                    reason=f"tracking failed ({result.reason}); too few points with a depth "
                                           "to re-initialise")
            return self._finish(frame, left, new_kf.T_world_cam, FrameOutcome.REINITIALISED, result, t0,
                                reason=f"tracking failed ({result.reason})")

        T_world = kf.T_world_cam.compose(result.T_keyframe_frame)
        suspect = self._suspect_reason(frame, kf, last, T_pred, T_world)
        if suspect is not None:  # keeps the prediction, like a lost frame; no keyframe, not a candidate
            return self._finish(frame, left, T_pred, FrameOutcome.SUSPECT, result, t0, reason=suspect,
                                T_keyframe_frame=kf.T_world_cam.between(T_pred))
        plain = FrameOutcome.TRACKED if self._flow_reason is None else FrameOutcome.RECOVERED
        if needs_keyframe(self.pinhole, kf.points, result, self._keyframe_rule):
            new_kf = self._make_keyframe_if_possible(frame, left, T_world, (kf.index, result.affine), pyr)
            if new_kf is not None:
                return self._finish(frame, left, new_kf.T_world_cam, FrameOutcome.KEYFRAME, result, t0)
            return self._finish(frame, left, T_world, plain, result, t0, candidate=False,
                                T_keyframe_frame=result.T_keyframe_frame)
        return self._finish(frame, left, T_world, plain, result, t0, T_keyframe_frame=result.T_keyframe_frame)

    def trajectory(self, name: str = "gtvo") -> Trajectory:
        """The estimated left-camera trajectory so far (every frame; window mode: call :meth:`finish`
        after the last frame so that the last keyframes are optimised too)."""
        if not self.estimates:
            raise InputError("no frame has been processed yet")
        return Trajectory(np.array([e.timestamp for e in self.estimates]),
                          np.stack([e.T_world_cam for e in self.estimates]), name=name)

    def point_cloud(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Every keyframe's points in the world frame (N, 3) and their intensities (N,), unfiltered
        (points with a non-positive inverse depth would be mirrored: see :meth:`map_points`)."""
        pts, vals = [], []
        for kf in self.keyframes:
            pts.append(self._world_points(kf))
            vals.append(kf.points.intensity)
        if not pts:
            return np.zeros((0, 3)), np.zeros(0)
        return np.concatenate(pts), np.concatenate(vals)

    def covariance(self, keyframe: int | Keyframe, inflation: float = 1.0) -> NDArray[np.float64] | None:
        """The 6x6 pose covariance of a keyframe (its frame index, or the :class:`Keyframe`) from the
        last window optimisation it was part of: GTSAM's tangent order ``[rotation, translation]``,
        right perturbation ``T = T_hat * Exp(xi)`` (``xi`` in the keyframe's own camera frame),
        relative to the world frame fixed by the first keyframe (docs/window.md, "Pose covariances").

        None when no covariance was computed for it: track mode, ``WindowConfig.covariances=False``,
        or a keyframe no window optimisation included yet (the newest keyframes while frames are
        still processed, until the next optimisation or :meth:`finish`). Raises
        :class:`InputError` for a frame index that is not a keyframe.

        ``inflation`` multiplies the window's covariance: the window's marginals are optimistic
        (measured on noisy synthetic sequences: mean NEES 4-8x the consistent value, docs/benchmarks.md,
        "Covariance honesty (NEES)"); 1.0 returns the window's own.
        """
        if not (np.isfinite(inflation) and inflation > 0):
            raise InputError(f"covariance inflation must be positive, got {inflation!r}")
        index = keyframe.index if isinstance(keyframe, Keyframe) else int(keyframe)
        if index not in self._keyframe_by_index:
            raise InputError(f"frame {index} is not a keyframe of this run")
        if self.window is None:
            return None
        P = self.window.covariances.get(index)
        return None if P is None else float(inflation) * P
    def map_points(self, keyframe_poses: Mapping[int, NDArray[np.float64]] | None = None) -> MapPoints:
        """The keyframe points whose depth the run constrains, in the world frame (what ``points.ply``
        holds): inverse depth positive, relative depth sigma bounded and, for keyframes that a window
        optimisation included, seen from enough keyframes in one (:mod:`gtvo.core.map_points`); the
        rest counted.

        ``keyframe_poses``: ``{keyframe index: 4x4 T_world_cam}`` to place keyframes elsewhere than
        at their odometry poses (e.g. after loop closing); a keyframe missing from it keeps its own.
        """
        pts, vals = [np.zeros((0, 3))], [np.zeros(0)]
        left_out: dict[str, int] = {}
        for kf in self.keyframes:
            # keyframes no window optimisation included (track mode, a run with one keyframe)
            # keep their measured depths, under the depth rules alone
            observed = self._observed.get(kf.index)
            seen = None if observed is None else 1 + observed
            keep, out = constrained_mask(kf.points.inverse_depth, kf.points.variance, seen)
            for k, v in out.items():
                left_out[k] = left_out.get(k, 0) + v
            T = None if keyframe_poses is None else keyframe_poses.get(kf.index)
            pts.append(self._world_points(kf, T)[keep])
            vals.append(np.asarray(kf.points.intensity, dtype=float)[keep])
        return MapPoints(np.concatenate(pts), np.concatenate(vals), left_out)

    def _world_points(self, kf: Keyframe, T_world_cam: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        with np.errstate(divide="ignore", invalid="ignore"):
            X = self.pinhole.backproject_inverse_depth(kf.points.pixels, kf.points.inverse_depth)
        T = kf.T_world_cam.matrix() if T_world_cam is None else np.asarray(T_world_cam, dtype=float)
        return X @ T[:3, :3].T + T[:3, 3]

    # -- internals ------------------------------------------------------------------------------
    @timed("tracking", absorb=True)
    def _track(self, kf: Keyframe, pyr, T_pred: gtsam.Pose3, last: gtsam.Pose3,
               left: NDArray[np.float32]) -> TrackingResult:
        """Track against ``kf`` from several initial guesses (motion model, no motion, keyframe);
        when all fail, from the optical-flow guess (``config.flow_fallback``)."""
        assert kf.tracker is not None
        self._flow_reason = None
        guesses = [kf.T_world_cam.between(T_pred), kf.T_world_cam.between(last), gtsam.Pose3()]
        prev_rms = self._last_rms()
        solver = track_handrolled if self.config.solver.tracker == "handrolled" else track_gtsam
        affine = self._affine_guess(kf)
        factor = self.config.motion_model.accept_rms_factor
        result = track_with_guesses(kf.tracker, pyr, guesses, affine, solver=solver,
                                    accept_rms=0.0 if prev_rms is None else factor * prev_rms)
        if result.success or self.config.flow_fallback is None or kf.image is None:
            return result
        flow = optical_flow_pose(self.pinhole, kf.image, kf.points.pixels, kf.points.inverse_depth, left,
                                 self.config.flow_fallback)
        if flow is None:
            result.reason = f"{result.reason}; no optical-flow guess"
            return result
        retry = solver(kf.tracker, pyr, rigid_pose(flow.T_keyframe_frame), affine)
        if retry.success:
            self.flow_recoveries += 1
            self._flow_reason = f"tracked from the optical-flow guess (from the motion model: {result.reason})"
            return retry
        result.reason = f"{result.reason}; from the optical-flow guess: {retry.reason}"
        return result

    def _last_rms(self) -> float | None:
        for e in reversed(self.estimates):
            if e.tracking is not None and e.tracking.success and not e.suspect:
                return e.tracking.rms
        return None

    def _affine_guess(self, kf: Keyframe) -> NDArray[np.float64]:
        """The last frame's affine brightness if it was tracked against ``kf``, else (0, 0)."""
        last = self._good_estimates(1)[0]
        if last.keyframe_index == kf.index and last.tracking is not None and last.tracking.success:
            return last.tracking.affine.copy()
        return np.zeros(2)

    def _predict(self, timestamp: float) -> gtsam.Pose3:
        """Motion-model guess of ``T_world_cam`` at ``timestamp``."""
        good = self._good_estimates(2)  # suspect frames are left out: the step spans them
        last = rigid_pose(good[-1].T_world_cam)
        if len(good) < 2:
            return last
        prev = rigid_pose(good[-2].T_world_cam)
        dt_prev = good[-1].timestamp - good[-2].timestamp
        dt = timestamp - good[-1].timestamp
        if self._kalman is not None and self._kalman.initialized:
            from gtvo.motion.model import T_world_cam_from_planar_pose  # noqa: PLC0415

            X, Z, theta = self._kalman.predict_pose(dt)
            planar = T_world_cam_from_planar_pose(X, Z, theta, last.matrix())
            return rigid_pose(planar)
        # constant velocity, scaled to the time step
        xi = gtsam.Pose3.Logmap(prev.between(last)) * (dt / dt_prev if dt_prev > 0 else 1.0)
        return last.compose(gtsam.Pose3.Expmap(xi))

    def _good_estimates(self, n: int) -> list[FrameEstimate]:
        """The last ``n`` (or fewer) estimates that are not suspect, oldest first."""
        out: list[FrameEstimate] = []
        for e in reversed(self.estimates):
            if not e.suspect:
                out.append(e)
                if len(out) == n:
                    break
        return out[::-1]

    def _suspect_reason(self, frame: Frame, kf: Keyframe, last: gtsam.Pose3, T_pred: gtsam.Pose3,
                        T_tracked: gtsam.Pose3) -> str | None:
        """Why the tracked frame is suspect (:mod:`gtvo.frontend.frame_checks`), or None.
        ``last``: the last good frame's pose (moved along with a promoted keyframe)."""
        good = self._good_estimates(2)
        if len(good) < 2:  # no motion model yet
            return None
        dt, dt_ref = frame.timestamp - good[1].timestamp, good[1].timestamp - good[0].timestamp
        if not (np.isfinite(dt) and np.isfinite(dt_ref) and dt_ref > 0):  # no usable times: frame counts
            dt, dt_ref = frame.index - good[1].index, good[1].index - good[0].index
        step = measure_step(self.pinhole, kf.points, kf.T_world_cam, last, T_pred, T_tracked, dt / dt_ref)
        previous = self.estimates[-1]
        return self._checker.check(step, good[1].index, previous.index if previous.suspect else None)

    def _mark_last_as_keyframe(self) -> None:
        """Record that the last good frame (the candidate) was promoted to a keyframe."""
        i = next(i for i in range(len(self.estimates) - 1, -1, -1) if not self.estimates[i].suspect)
        self.estimates[i] = dataclasses.replace(self.estimates[i], outcome=FrameOutcome.KEYFRAME)

    def _finish(self, frame: Frame, left: NDArray[np.float32], T_world_cam: gtsam.Pose3, outcome: FrameOutcome,
                result: TrackingResult | None, t0: float, candidate: bool = True,
                T_keyframe_frame: gtsam.Pose3 | None = None, reason: str = "") -> FrameEstimate:
        """Record the frame's estimate. ``candidate``: the frame may be promoted to a keyframe by
        the next frame (not when it is lost or just failed to become one; a suspect frame leaves
        the candidate as it was); ``T_keyframe_frame``: a non-keyframe's pose relative to its
        keyframe; ``reason``: why it was lost, re-initialised or suspect."""
        tracked = result is not None and outcome is not FrameOutcome.REINITIALISED
        kf_index = self.keyframes[-1].index if tracked else frame.index
        if tracked and outcome is FrameOutcome.KEYFRAME:  # tracked against the keyframe before this one
            kf_index = self.keyframes[-2].index
        lost = outcome is FrameOutcome.LOST
        flow = tracked and outcome is not FrameOutcome.LOST and self._flow_reason is not None
        if flow and not reason:
            reason = self._flow_reason or ""
        est = FrameEstimate(frame.index, float(frame.timestamp), T_world_cam.matrix(), outcome, result,
                            time.perf_counter() - t0, kf_index, T_keyframe_frame, reason, flow)
        self.estimates.append(est)
        if est.suspect:  # not fed to the motion model; the candidate stays the last good frame
            return est
        self._previous = (frame, left) if candidate and not lost else None
        if self._kalman is not None:
            from gtvo.motion.model import planar_pose_from_T_world_cam  # noqa: PLC0415

            z = planar_pose_from_T_world_cam(est.T_world_cam)
            if not self._kalman.initialized:
                self._kalman.initialize(z)
            else:
                good = self._good_estimates(2)
                dt = good[1].timestamp - good[0].timestamp  # over suspect frames, which it never saw
                if lost:  # the pose is the filter's own prediction: no measurement to fuse
                    self._kalman.predict(dt)
                else:
                    self._kalman.step(z, dt)
        return est
