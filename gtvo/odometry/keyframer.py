"""The keyframer: the odometry's keyframes and their link to the sliding window.

:class:`Keyframer` owns the keyframes (DSO's ``FullSystemMakeKeyframe`` and the window's side of
``FullSystemOptimize`` in one place): it makes a keyframe from a frame (its points with depths,
:mod:`gtvo.odometry.keyframe_points`; its tracker), and in window mode adds it to the
:class:`gtvo.window.SlidingWindowOptimizer`, optimises the window on the schedule of
:class:`gtvo.odometry.window_schedule.WindowSchedule`, writes the optimised poses and depths back
to its keyframes and has the history re-express the frames tracked against them. When the window
releases the rig offset's ``delta_x``, the window keyframes' depths are searched again against the
corrected right image. The rig offset itself lives in the window (``window.rig``).
"""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.photometric import GradientImage
from gtvo.config import OdometryConfig
from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.core.image import to_float_gray
from gtvo.core.timing import stage
from gtvo.datasets.sequence import Frame
from gtvo.frontend import KeyframePoints
from gtvo.frontend.keyframes import needs_keyframe
from gtvo.frontend.rig_offset import correct_right_image
from gtvo.frontend.stereo_affine import estimate_stereo_affine
from gtvo.frontend.stereo_depth import stereo_inverse_depth
from gtvo.frontend.tracking import TrackingKeyframe, TrackingResult, frame_pyramid
from gtvo.odometry.estimates import Keyframe, TooFewPoints, rigid_pose
from gtvo.odometry.history import FrameHistory
from gtvo.odometry.keyframe_points import frame_points
from gtvo.odometry.window_schedule import WindowSchedule
from gtvo.window import SlidingWindowOptimizer, WindowKeyframe, WindowResult
from gtvo.window.depth_change import tracked_translation_scale
from gtvo.window.rig import RigOffset
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
        window: the sliding window (window mode), else None.
        window_results: one :class:`gtvo.window.WindowResult` per window optimisation.
        schedule: when the window is optimised.
        candidate: the last good frame with its left image, which the next frame may promote to a
            keyframe when it cannot be tracked against the latest one (None: no candidate).
    """

    def __init__(self, camera: StereoCamera | PinholeCamera, config: OdometryConfig, history: FrameHistory,
                 wheel: WheelCalibration | None = None) -> None:
        self.camera = camera
        self.pinhole = camera.left if isinstance(camera, StereoCamera) else camera
        self.config = config
        self.history = history
        self.keyframes: list[Keyframe] = []
        self.window: SlidingWindowOptimizer | None = None
        self.window_results: list[WindowResult] = []
        self.schedule = WindowSchedule(config.window, config.photometric, self.pinhole)
        self.candidate: tuple[Frame, NDArray[np.float32]] | None = None
        self._by_index: dict[int, Keyframe] = {}
        self._window_affine: dict[int, NDArray[np.float64]] = {}  # keyframe index -> (a, b) in the window
        # keyframe index -> per point, the most other keyframes a window optimisation compared it with
        self._observed: dict[int, NDArray[np.int64]] = {}
        if config.mode == "window":
            baseline = camera.baseline if isinstance(camera, StereoCamera) else None
            wcfg = config.window
            rig = baseline is not None and wcfg.rig_calibration and wcfg.backend == "lm"
            self.window = SlidingWindowOptimizer(self.pinhole, baseline, wcfg, rig_offset=np.zeros(2) if rig else None,
                                                 photometric=config.photometric,
                                                 wheel=wheel if wcfg.backend == "lm" else None)
            # the whole-log refinement needs every keyframe (gtvo.refinement): kept only when it runs
            self.window.retain_keyframes = config.refine.enabled

    @property
    def rig(self) -> RigOffset | None:
        """The rig offset the window estimates (its one owner), None when not estimated."""
        return None if self.window is None else self.window.rig

    def keyframe(self, index: int) -> Keyframe | None:
        """The keyframe made from frame ``index``, None when that frame is not a keyframe."""
        return self._by_index.get(index)

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
        right = None  # the right image in grey levels, converted once for the stereo search and the window
        if isinstance(self.camera, StereoCamera) and frame.right is not None:
            right = to_float_gray(frame.right, f"frame {frame.index} right image")
        pts = frame_points(frame, left, right, self.camera, self.config, self.rig)
        if len(pts) < self.config.tracking.min_valid_points:
            raise TooFewPoints(f"frame {frame.index}: only {len(pts)} points with a valid depth; "
                               "the images may be blank or the stereo calibration wrong")
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
        """Optimise the keyframes that joined the window since its last optimisation and re-express
        their frames; nothing to do in track mode or when none is waiting."""
        if self.window is not None and self.schedule.waiting and self._optimize_window():
            self._re_express()

    # -- the window link ------------------------------------------------------------------------
    def _join_window(self, frame: Frame, right_image: NDArray[np.float32] | None, T_world_cam: gtsam.Pose3,
                     pts: KeyframePoints,
                     tracked: tuple[int, NDArray[np.float64]] | None,
                     pyramid: list[GradientImage]) -> tuple[gtsam.Pose3, KeyframePoints]:
        """Add a new keyframe to the window and optimise on schedule; returns its pose and points
        (optimised when the window ran).

        The new keyframe's affine in the window's brightness reference: a frame tracked with
        ``(a, b)`` against a keyframe at ``(a_h, b_h)`` sees ``exp(a) I_h + b``, i.e.
        ``a_t = a_h + a``, ``b_t = b + exp(a) b_h``.
        """
        assert self.window is not None
        affine = np.zeros(2)
        if tracked is not None and tracked[0] in self._window_affine:
            a_h, b_h = self._window_affine[tracked[0]]
            a, b = np.asarray(tracked[1], dtype=float)
            affine = np.array([a_h + a, b + np.exp(a) * b_h])
        elif self.window.keyframes:
            affine = self.window.keyframes[-1].affine.copy()
        right = None
        clip = self.config.photometric.clip_range
        stereo_affine = np.zeros(2)
        left_img = pyramid[0]  # the window keyframe's left image with gradients: the pyramid's level 0
        if isinstance(self.camera, StereoCamera):
            assert right_image is not None
            with stage("keyframe_setup"):  # the right image with gradients
                right = GradientImage(right_image, clip_range=clip)
            rig = self.rig
            stereo_affine = estimate_stereo_affine(self.pinhole, self.camera.baseline, left_img, right, pts.pixels,
                                                   pts.inverse_depth, pts.variance,
                                                   sigma_intensity=self.config.photometric.sigma_intensity,
                                                   offset=None if rig is None else rig.offset)
        wk = WindowKeyframe(frame.index, T_world_cam, affine, left_img, pts.pixels, pts.inverse_depth,
                            pts.variance, right=right, depth_prior=right is None, stereo_affine=stereo_affine,
                            timestamp=float(frame.timestamp) if np.isfinite(frame.timestamp) else None)
        self.window.add_keyframe(wk)
        self.schedule.waiting += 1
        follows = bool(self.keyframes) and self.history.latest_other_than(frame.index) == self.keyframes[-1].index
        if self.keyframes and self.schedule.may_wait(tracked is not None, follows, self.keyframes[-1].T_world_cam,
                                                      T_world_cam, pts):
            self._window_affine = {w.index: w.affine.copy() for w in self.window.keyframes}
            return T_world_cam, pts
        if not self._optimize_window():  # sets _window_affine too
            return T_world_cam, pts
        return wk.pose, dataclasses.replace(pts, inverse_depth=wk.inverse_depth.copy())

    def _optimize_window(self) -> bool:
        """Optimise the window and write its poses and depths back to the keyframes made so far
        (the newest one, not made yet, takes them from the window keyframe); False when the window
        had nothing to optimise (fewer than two keyframes, no target)."""
        assert self.window is not None
        self.schedule.waiting = 0
        rig = self.window.rig
        x_was_estimated = rig is not None and rig.x_estimated
        held_depths = ({w.index: w.inverse_depth.copy() for w in self.window.keyframes}
                       if rig is not None and not x_was_estimated else None)
        res = self.window.optimize(self.config.solver.window)
        if rig is not None and rig.x_estimated and not x_was_estimated:
            assert held_depths is not None
            self._research_window_depths(rig)
            res = self.window.optimize(self.config.solver.window) or res
            self._rescale_tracked_frames(held_depths)
        self._window_affine = {w.index: w.affine.copy() for w in self.window.keyframes}
        if res is None:
            return False
        self.window_results.append(res)
        for index, n in self.window.observation_counts().items():
            prev = self._observed.get(index)
            self._observed[index] = n if prev is None or len(prev) != len(n) else np.maximum(prev, n)
        for w in self.window.keyframes:
            old = self._by_index.get(w.index)
            if old is not None:
                old.T_world_cam = w.pose
                old.points = dataclasses.replace(old.points, inverse_depth=w.inverse_depth.copy())
        return True

    def _rescale_tracked_frames(self, held_depths: dict[int, NDArray[np.float64]]) -> None:
        """Once the window releases ``delta_x``, the frames tracked against its keyframes while it
        was held have translations in the scale of the depths then (``held_depths``, by keyframe
        index): each is scaled by :func:`gtvo.window.depth_change.tracked_translation_scale` of its
        keyframe's depths before and after (docs/window.md, "Rig calibration", the hold's transient)."""
        assert self.window is not None
        scales = {w.index: tracked_translation_scale(held_depths[w.index], w.inverse_depth)
                  for w in self.window.keyframes
                  if w.index in held_depths and held_depths[w.index].shape == w.inverse_depth.shape}
        self.history.rescale_tracked(scales, self._by_index)

    def _research_window_depths(self, rig: RigOffset) -> None:
        """Once the window releases ``delta_x`` (docs/window.md, "Rig calibration"), its keyframes'
        depths, initialised with the right image corrected by the offset known then, are searched
        again against the right image corrected by the estimate (and their stereo affine fitted
        again): a point whose new search matches takes its inverse depth and variance."""
        assert self.window is not None and isinstance(self.camera, StereoCamera)
        for w in self.window.keyframes:
            if w.right is None:
                continue
            right = correct_right_image(w.right.image, rig.offset)
            res = stereo_inverse_depth(w.image.image, right, self.camera, w.pixels, self.config.frontend.stereo,
                                       self.config.photometric.clip_range)
            w.inverse_depth = np.where(res.valid, res.inverse_depth, w.inverse_depth)
            w.variance = np.where(res.valid, res.variance, w.variance)
            w.stereo_affine = estimate_stereo_affine(self.pinhole, self.camera.baseline, w.image, w.right, w.pixels,
                                                     w.inverse_depth, w.variance,
                                                     sigma_intensity=self.config.photometric.sigma_intensity,
                                                     offset=rig.offset)

    def _re_express(self) -> None:
        """Have the history re-express the frames of the window's keyframes at their new poses."""
        assert self.window is not None
        if self.window.keyframes:
            self.history.re_express(self._by_index, since=self.window.keyframes[0].index)
