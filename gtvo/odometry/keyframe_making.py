"""How the odometry makes keyframes: points with depths from stereo or RGB-D, the rig's vertical
offset at the start, joining the sliding window and writing its results back (DSO's
``FullSystemMakeKeyframe``: one concern of :class:`gtvo.odometry.VisualOdometry` in its own file).

:class:`KeyframeMaking` holds methods only; :class:`gtvo.odometry.VisualOdometry` owns the state
they use (``config``, ``camera``, ``pinhole``, ``keyframes``, ``estimates``, ``window``, ...).
"""

from __future__ import annotations

import dataclasses
from contextlib import nullcontext

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.photometric import GradientImage
from gtvo.core.camera import StereoCamera
from gtvo.core.timing import stage
from gtvo.errors import InputError
from gtvo.frontend import KeyframePoints, init_keyframe_points
from gtvo.frontend.stereo_depth import stereo_inverse_depth
from gtvo.core.image import to_float_gray
from gtvo.datasets.sequence import Frame
from gtvo.frontend.tracking import TrackingKeyframe, frame_pyramid
from gtvo.frontend.stereo_affine import estimate_stereo_affine
from gtvo.frontend.rgbd import rgbd_keyframe_points
from gtvo.frontend.rig_offset import correct_right_image, estimate_vertical_offset
from gtvo.frontend.point_selection import select_points
from gtvo.odometry.estimates import TooFewPoints, rigid_pose
from gtvo.odometry.estimates import Keyframe
from gtvo.window import WindowKeyframe
from gtvo.window.depth_change import tracked_translation_scale
from gtvo.window.problem import rig_offset_significant


class KeyframeMaking:
    """The keyframe-making part of :class:`gtvo.odometry.VisualOdometry` (module docstring)."""

    def _frame_points(self, frame: Frame, left: NDArray[np.float32]) -> KeyframePoints:
        cfg = self.config.frontend
        if isinstance(self.camera, StereoCamera):
            if frame.right is None:
                raise InputError(f"frame {frame.index}: stereo odometry needs a right image")
            right = frame.right
            if self.rig_offset is not None:
                if not self.keyframes and self.rig_initial is None:
                    self._initial_vertical_offset(left, right)
                right = correct_right_image(right, self.rig_offset)
            return init_keyframe_points(left, right, self.camera, target=cfg.points_per_keyframe,
                                        selection=cfg.points, stereo=cfg.stereo,
                                        clip_range=self.config.photometric.clip_range)
        if frame.depth is None:
            raise InputError(f"frame {frame.index}: RGB-D odometry needs a depth image")
        return rgbd_keyframe_points(left, frame.depth, cfg.points_per_keyframe, cfg.depth_sigma_model, cfg.points)

    def _initial_vertical_offset(self, left: NDArray[np.float32], right: NDArray) -> None:
        """The rig's vertical offset from the first stereo pair (a 2-D search), the window's starting value.

        Raises:
            TooFewPoints: no stereo match survives at any row shift (an InputError on the first frame).
        """
        assert self.rig_offset is not None and isinstance(self.camera, StereoCamera)
        fcfg = self.config.frontend
        pixels = select_points(left, fcfg.points_per_keyframe, **dataclasses.asdict(fcfg.points))
        est = estimate_vertical_offset(left, right, self.camera, pixels, max_disparity=fcfg.stereo.max_disparity)
        self.rig_initial = est
        if est is None:
            raise TooFewPoints("the first stereo pair has no stereo match at any vertical offset within "
                                "+-2 rows: the right camera is offset too far from its calibration (or the "
                                "images hold no texture); no rig offset can be estimated")
        assert self.window is not None
        if rig_offset_significant(est.delta_y, est.sigma, 1):  # known: corrected, delta_x to follow
            self.rig_offset = np.array([0.0, est.delta_y])
            self.window.rig_y_known = True
        else:  # the rectified model until the window's data say otherwise (both axes tested)
            self.rig_offset = np.zeros(2)
            self.window.rig_rectified = True
        self.window.rig_offset = self.rig_offset.copy()

    def _make_keyframe(self, frame: Frame, left: NDArray[np.float32], T_world_cam: gtsam.Pose3,
                       tracked: tuple[int, NDArray[np.float64]] | None = None,
                       pyramid: list[GradientImage] | None = None) -> Keyframe:
        """Make ``frame`` a keyframe at ``T_world_cam``; in window mode, add it to the window and
        optimise (``tracked``: the keyframe it was tracked against and its affine relative to it;
        ``pyramid``: the frame's pyramid from its tracking, shared with the keyframe's tracker and
        the window instead of being computed again).

        Raises:
            InputError: the frame has fewer than ``tracking.min_valid_points`` points with a depth
                (the first frame: nothing can start; later frames go through
                :meth:`_make_keyframe_if_possible`).
        """
        pts = self._frame_points(frame, left)
        if len(pts) < self.config.tracking.min_valid_points:
            raise TooFewPoints(f"frame {frame.index}: only {len(pts)} points with a valid depth; "
                                "the images may be blank or the stereo calibration wrong")
        if self.window is not None:
            if pyramid is None:  # one pyramid for the window keyframe's image and the tracker (no tracking made it)
                with stage("keyframe_setup"):
                    pyramid = frame_pyramid(left, self.config.tracking.levels, self.config.tracking.clip_range)
            T_world_cam, pts = self._window_update(frame, left, T_world_cam, pts, tracked, pyramid)
        with stage("keyframe_setup"):  # the new keyframe's tracker: its pyramid with gradients (or the frame's)
            tracker = TrackingKeyframe(self.pinhole, left, pts.pixels, pts.inverse_depth, pts.variance, (0.0, 0.0),
                                       self.config.tracking, pyramid=pyramid)
        image = left if self.config.flow_fallback is not None else None  # converted only if the fallback runs
        kf = Keyframe(frame.index, rigid_pose(T_world_cam.matrix()), pts, tracker, image)
        if self.keyframes:
            self.keyframes[-1].tracker = self.keyframes[-1].image = None
        self.keyframes.append(kf)
        self._keyframe_by_index[kf.index] = kf
        if self.window is not None:
            self._refresh_estimates()
        return kf

    def _make_keyframe_if_possible(self, frame: Frame, left: NDArray[np.float32], T_world_cam: gtsam.Pose3,
                                   tracked: tuple[int, NDArray[np.float64]] | None = None,
                                   pyramid: list[GradientImage] | None = None) -> Keyframe | None:
        """:meth:`_make_keyframe`, or None (nothing changed) when the frame has too few points."""
        try:
            return self._make_keyframe(frame, left, T_world_cam, tracked, pyramid)
        except TooFewPoints:
            return None

    def _window_update(self, frame: Frame, left: NDArray[np.float32], T_world_cam: gtsam.Pose3,
                       pts: KeyframePoints, tracked: tuple[int, NDArray[np.float64]] | None,
                       pyramid: list[GradientImage] | None = None) -> tuple[gtsam.Pose3, KeyframePoints]:
        """Add a new keyframe to the window, optimise it, write the results back to the keyframes.

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
        with stage("keyframe_setup"):  # the window keyframe's images with gradients
            left_img = pyramid[0] if pyramid is not None else GradientImage(left, clip_range=clip)
            if isinstance(self.camera, StereoCamera):
                right = GradientImage(to_float_gray(frame.right, f"frame {frame.index} right image"), clip_range=clip)
        stereo_affine = np.zeros(2)
        if isinstance(self.camera, StereoCamera):
            stereo_affine = estimate_stereo_affine(self.pinhole, self.camera.baseline, left_img, right, pts.pixels,
                                                   pts.inverse_depth, pts.variance,
                                                   sigma_intensity=self.config.window.sigma_intensity,
                                                   offset=self.rig_offset)
        wk = WindowKeyframe(frame.index, T_world_cam, affine, left_img, pts.pixels, pts.inverse_depth,
                            pts.variance, right=right, depth_prior=right is None, stereo_affine=stereo_affine,
                            timestamp=float(frame.timestamp) if np.isfinite(frame.timestamp) else None)
        self.window.add_keyframe(wk)
        self._window_waiting += 1
        wcfg = self.config.window
        defer = (tracked is not None and wcfg.backend == "lm" and self._window_waiting < wcfg.optimize_every
                 and self._follows_last_keyframe(frame.index) and self._stereo_depths_suffice(T_world_cam, pts))
        if defer:
            self._window_affine = {w.index: w.affine.copy() for w in self.window.keyframes}
            return T_world_cam, pts
        if not self._optimize_window():  # sets _window_affine too
            return T_world_cam, pts
        return wk.pose, dataclasses.replace(pts, inverse_depth=wk.inverse_depth.copy())

    def _follows_last_keyframe(self, index: int) -> bool:
        """True when frame ``index`` comes right after the last keyframe: no other frame was tracked
        against it (keyframes at every frame, a car at 10 Hz). Only then may the window's
        optimisation wait: a frame tracked against a keyframe the window has not refined yet keeps
        that keyframe's stereo depths in its pose (measured: up to 1.7x the ATE on noisy synthetic
        loops when optimisations waited regardless; docs/window.md)."""
        if not self.keyframes:
            return False
        last = self.keyframes[-1].index
        for e in reversed(self.estimates):
            if e.index == index:  # the frame being made a keyframe (promoted after it was tracked)
                continue
            return e.index == last
        return False

    def finish(self) -> None:
        """Optimise the keyframes that joined the window since its last optimisation
        (``WindowConfig.optimize_every`` > 1) and re-express their frames; nothing to do in track
        mode or when none is waiting. Call it after the last frame (``gtvo.run`` does); frames may
        still follow (the next keyframe joins the window as usual)."""
        if self.window is None or not self._window_waiting:
            return
        with self.clock.activate("other") if self.clock is not None else nullcontext(), single_threaded_blas():
            if self._optimize_window():
                self._refresh_estimates()

    def _stereo_depths_suffice(self, T_world_cam: gtsam.Pose3, pts: KeyframePoints) -> bool:
        """True when the new keyframe's own (unrefined) depths are good enough to track the next
        frame against: their inverse-depth error moves a point by less than the residual pattern's
        radius over one more step like the last one, ``fx |t| sqrt(median V) < max |pattern offset|``
        (``t``: the translation from the last keyframe; 2 px for DSO's pattern). Then the tracker
        still compares the right pixels, and the window may refine the keyframe later
        (docs/window.md, "When the window is optimised")."""
        last = self.keyframes[-1].T_world_cam
        step = float(np.linalg.norm(last.between(T_world_cam).translation()))
        error_px = float(self.pinhole.fx) * step * float(np.sqrt(np.median(pts.variance)))
        radius = float(np.max(np.linalg.norm(np.asarray(self.config.window.pattern, dtype=float), axis=1)))
        return error_px < radius

    def _optimize_window(self) -> bool:
        """Optimise the window and write its poses and depths back to the keyframes made so far
        (the newest one, not made yet, takes them from the window keyframe); False when the window
        had nothing to optimise (fewer than two keyframes, no target)."""
        assert self.window is not None
        self._window_waiting = 0
        x_was_estimated = self.window.rig_x_estimated
        held_depths = ({w.index: w.inverse_depth.copy() for w in self.window.keyframes}
                       if self.window.rig_offset is not None and not x_was_estimated else None)
        res = self.window.optimize(self.config.solver.window)
        if self.window.rig_offset is not None:
            self.rig_offset = self.window.rig_offset.copy()
            if self.window.rig_x_estimated and not x_was_estimated:
                self._reinitialise_window_depths()
                res = self.window.optimize(self.config.solver.window) or res
                self.rig_offset = self.window.rig_offset.copy()
                assert held_depths is not None
                self._rescale_tracked_frames(held_depths)
        self._window_affine = {w.index: w.affine.copy() for w in self.window.keyframes}
        if res is None:
            return False
        self.window_results.append(res)
        for index, n in self.window.observation_counts().items():
            prev = self._observed.get(index)
            self._observed[index] = n if prev is None or len(prev) != len(n) else np.maximum(prev, n)
        for w in self.window.keyframes:
            old = self._keyframe_by_index.get(w.index)
            if old is not None:
                old.T_world_cam = w.pose
                old.points = dataclasses.replace(old.points, inverse_depth=w.inverse_depth.copy())
        return True

    def _rescale_tracked_frames(self, held_depths: dict[int, NDArray[np.float64]]) -> None:
        """Once ``delta_x`` is released, the frames tracked against the window's keyframes while it was
        held have translations in the scale of the depths then (``held_depths``, by keyframe index):
        each is multiplied by :func:`gtvo.window.depth_change.tracked_translation_scale` of its
        keyframe's depths before and after (docs/window.md, "Rig calibration", the hold's transient)."""
        assert self.window is not None
        scales = {w.index: tracked_translation_scale(held_depths[w.index], w.inverse_depth)
                  for w in self.window.keyframes if w.index in held_depths
                  and held_depths[w.index].shape == w.inverse_depth.shape}
        for i, e in enumerate(self.estimates):
            s = scales.get(e.keyframe_index)
            if s is None or e.T_keyframe_frame is None or e.index in self._keyframe_by_index:
                continue
            T = e.T_keyframe_frame
            self.estimates[i] = dataclasses.replace(
                e, T_keyframe_frame=gtsam.Pose3(T.rotation(), s * np.asarray(T.translation())))

    def _reinitialise_window_depths(self) -> None:
        """Once the window estimates ``delta_x`` (docs/window.md, "Rig calibration"), its keyframes'
        depths, initialised with the right image corrected by the offset known then, are searched
        again against the right image corrected by the estimate (and their stereo affine fitted
        again): a point whose new search matches takes its inverse depth and variance."""
        assert self.window is not None and self.rig_offset is not None and isinstance(self.camera, StereoCamera)
        options = dataclasses.asdict(self.config.frontend.stereo)
        for w in self.window.keyframes:
            if w.right is None:
                continue
            right = correct_right_image(w.right.image, self.rig_offset)
            res = stereo_inverse_depth(w.image.image, right, self.camera, w.pixels, **options,
                                       clip_range=self.config.photometric.clip_range)
            w.inverse_depth = np.where(res.valid, res.inverse_depth, w.inverse_depth)
            w.variance = np.where(res.valid, res.variance, w.variance)
            w.stereo_affine = estimate_stereo_affine(self.pinhole, self.camera.baseline, w.image, w.right, w.pixels,
                                                     w.inverse_depth, w.variance,
                                                     sigma_intensity=self.config.window.sigma_intensity,
                                                     offset=self.rig_offset)

    def _refresh_estimates(self) -> None:
        """Re-express the poses of frames whose keyframe the window moved.

        A keyframe's pose is its (optimised) keyframe pose; any other frame's is
        ``T_world_keyframe * T_keyframe_frame`` with its keyframe's current pose.
        """
        assert self.window is not None
        if not self.window.keyframes:
            return
        first = self.window.keyframes[0].index
        for i in range(len(self.estimates) - 1, -1, -1):
            e = self.estimates[i]
            if e.index < first:  # keyframe_index <= index: nothing older moved
                break
            if e.index in self._keyframe_by_index:
                T = self._keyframe_by_index[e.index].T_world_cam
            elif e.T_keyframe_frame is not None and e.keyframe_index in self._keyframe_by_index:
                T = self._keyframe_by_index[e.keyframe_index].T_world_cam.compose(e.T_keyframe_frame)
            else:
                continue
            self.estimates[i] = dataclasses.replace(e, T_world_cam=T.matrix())


_BLAS_CONTROLLER = None


def single_threaded_blas():
    """A context that limits BLAS to one thread (the controller is built once: it scans libraries)."""
    global _BLAS_CONTROLLER
    if _BLAS_CONTROLLER is None:
        from threadpoolctl import ThreadpoolController  # noqa: PLC0415

        _BLAS_CONTROLLER = ThreadpoolController()
    return _BLAS_CONTROLLER.limit(limits=1, user_api="blas")
