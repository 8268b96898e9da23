"""The window's side of the keyframer: a keyframe joins the window, the window is optimised, and
what the front end needs back from it (:class:`WindowUpdate`).

:class:`WindowLink` owns the :class:`gtvo.window.SlidingWindowOptimizer` and everything that only
the window's state decides: a new keyframe's affine brightness in the window's reference, the
right camera's brightness, the rig offset's release and the stereo search it triggers. The
keyframer drives it with plain data (:class:`KeyframeForWindow` in, :class:`WindowUpdate` out),
so the same link runs in the odometry's process (``window.parallel: false``: every update is
applied at once) or in a worker process beside the front end (:mod:`gtvo.odometry.window_worker`;
docs/window.md, "The window beside the tracker").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.photometric import GradientImage
from gtvo.config import OdometryConfig
from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.core.timing import stage
from gtvo.frontend import KeyframePoints
from gtvo.frontend.rig_offset import correct_right_image
from gtvo.frontend.stereo_affine import estimate_stereo_affine
from gtvo.frontend.stereo_depth import stereo_inverse_depth
from gtvo.window import SlidingWindowOptimizer, WindowKeyframe, WindowResult, WindowSettings
from gtvo.window.depth_change import tracked_translation_scale
from gtvo.window.rig import RigOffset
from gtvo.window.imu import ImuWindow
from gtvo.window.wheel import WheelCalibration

FloatArray = NDArray[np.float64]

#: Two poses whose 4x4 matrices differ by no more than this (rad, m) in every entry are the same
#: pose for :meth:`WindowLink._placed` (the front end's copy of a window pose, re-orthonormalised).
SAME_POSE = 1e-12


@dataclass
class KeyframeForWindow:
    """What a new keyframe brings to the window (no pyramid: the window needs level 0 only).

    Attributes:
        index: the frame index.
        timestamp: capture time (s), None when unknown.
        T_world_cam: its pose as the front end estimated it.
        points: its points with their stereo (or RGB-D) inverse depths.
        tracked: the keyframe it was tracked against and its affine ``(a, b)`` relative to it
            (None: not tracked, e.g. re-initialised).
        left: the left image with gradients (the tracker's pyramid level 0), or its grey levels
            (a worker builds the :class:`GradientImage`).
        right: the right image in grey levels (stereo), else None.
        anchor: parallel window only: ``(index, T_world_cam)`` of the keyframe the front end
            placed this one after, as the front end knew it; the window moves the new keyframe by
            the correction its own pose of that keyframe makes (None: placed as given).
    """

    index: int
    timestamp: float | None
    T_world_cam: gtsam.Pose3
    points: KeyframePoints
    tracked: tuple[int, FloatArray] | None
    left: GradientImage | NDArray[np.float32]
    right: NDArray[np.float32] | None
    anchor: tuple[int, FloatArray] | None = None


@dataclass
class WindowMember:
    """One keyframe of the window after an optimisation: what the front end writes back."""

    index: int
    pose: gtsam.Pose3
    inverse_depth: FloatArray
    #: the right camera's brightness relative to the left one (None: no right image)
    stereo_affine: FloatArray | None


@dataclass
class WindowUpdate:
    """What one window optimisation hands back to the front end (poses, depths, figures; no images).

    Attributes:
        members: the window's keyframes, oldest first, optimised.
        result: the optimisation's :class:`WindowResult` (its covariances included).
        observed: per keyframe index, per point: how many other keyframes it was compared with.
        tracked_scales: when the rig offset's ``delta_x`` was released: per keyframe index, the
            scale by which the frames tracked against it move (:mod:`gtvo.window.depth_change`).
        rig: the rig offset after the optimisation (None: not estimated).
        sensor_states: a window in a worker process: per sensor of the window
            (:attr:`gtvo.window.SlidingWindowOptimizer.sensors`, in order), what the front end
            reads of it (:meth:`CarriedSensor.window_state`); None in this process (the sensors
            are the front end's own).
    """

    members: list[WindowMember]
    result: WindowResult
    observed: dict[int, NDArray[np.int64]]
    tracked_scales: dict[int, float] | None
    rig: RigOffset | None
    sensor_states: list[Any] | None = None


class CarriedSensor(Protocol):
    """A window sensor (:class:`gtvo.window.problem.WindowSensor`) that a window in a worker process
    carries: the worker estimates its own copy, and each update it hands out brings the front end's
    copy up to date (the wheel calibration, :class:`gtvo.window.wheel.WheelCalibration`; the IMU,
    :class:`gtvo.window.imu.ImuWindow`)."""

    def window_state(self, indices: Sequence[int]) -> Any:
        """What the front end reads of the sensor between updates, as plain data (``indices``: the
        window's keyframes, for per-keyframe estimates)."""

    def take_window_state(self, state: Any) -> None:
        """Take a copy's :meth:`window_state` as this sensor's."""


class WindowLink:
    """The window and what only its state decides (module docstring).

    Args:
        camera: a :class:`StereoCamera` for stereo input, a :class:`PinholeCamera` for RGB-D.
        config: the run's settings.
        wheel: the wheel odometry's calibration the window estimates with its wheel factors (LM
            backend), or None.
        imu: the IMU's owner in the window (:class:`gtvo.window.imu.ImuWindow`), or None.
    """

    def __init__(self, camera: StereoCamera | PinholeCamera, config: OdometryConfig,
                 wheel: WheelCalibration | None = None, imu: ImuWindow | None = None) -> None:
        self.camera = camera
        self.pinhole = camera.left if isinstance(camera, StereoCamera) else camera
        self.config = config
        baseline = camera.baseline if isinstance(camera, StereoCamera) else None
        wcfg = config.window
        rig = baseline is not None and wcfg.rig_calibration and wcfg.backend == "lm"
        self.window = SlidingWindowOptimizer(self.pinhole, baseline, WindowSettings(wcfg, config.photometric),
                                             rig_offset=np.zeros(2) if rig else None, wheel=wheel)
        if imu is not None:
            self.window.use_imu(imu)
        # the whole-log refinement needs every keyframe (gtvo.refinement): kept only when it runs
        self.window.retain_keyframes = config.refine.enabled

    def join(self, request: KeyframeForWindow) -> None:
        """Add the keyframe to the window (the oldest leaves first when it is full).

        Its affine in the window's brightness reference: a frame tracked with ``(a, b)`` against a
        keyframe at ``(a_h, b_h)`` sees ``exp(a) I_h + b``, i.e. ``a_t = a_h + a``,
        ``b_t = b + exp(a) b_h``.
        """
        window = self.window
        window_affine = {w.index: w.affine for w in window.keyframes}
        affine = np.zeros(2)
        tracked = request.tracked
        if tracked is not None and tracked[0] in window_affine:
            a_h, b_h = window_affine[tracked[0]].copy()
            a, b = np.asarray(tracked[1], dtype=float)
            affine = np.array([a_h + a, b + np.exp(a) * b_h])
        elif window.keyframes:
            affine = window.keyframes[-1].affine.copy()
        clip = self.config.photometric.clip_range
        left_img = request.left
        if not isinstance(left_img, GradientImage):
            with stage("keyframe_setup"):
                left_img = GradientImage(left_img, clip_range=clip)
        right = None
        stereo_affine = np.zeros(2)
        pts = request.points
        if isinstance(self.camera, StereoCamera):
            assert request.right is not None
            with stage("keyframe_setup"):  # the right image with gradients
                right = GradientImage(request.right, clip_range=clip)
            rig = window.rig
            stereo_affine = estimate_stereo_affine(self.pinhole, self.camera.baseline, left_img, right, pts.pixels,
                                                   pts.inverse_depth, pts.variance,
                                                   sigma_intensity=self.config.photometric.sigma_intensity,
                                                   offset=None if rig is None else rig.offset)
        wk = WindowKeyframe(request.index, self._placed(request), affine, left_img, pts.pixels, pts.inverse_depth,
                            pts.variance, right=right, depth_prior=right is None, stereo_affine=stereo_affine,
                            timestamp=request.timestamp)
        window.add_keyframe(wk)

    def _placed(self, request: KeyframeForWindow) -> gtsam.Pose3:
        """The new keyframe's pose in the window: as given, or (``anchor``) moved with its anchor
        keyframe from where the front end knew it to where the window has it; not moved when the two
        agree to :data:`SAME_POSE` (every update applied already: a correction of rounding errors
        only, which would make the window's order differ from the sequential one in the last bits)."""
        if request.anchor is None:
            return request.T_world_cam
        index, T_front = request.anchor
        found = [w.pose for w in self.window.keyframes if w.index == index]
        if not found:
            return request.T_world_cam
        if np.allclose(found[0].matrix(), T_front, rtol=0.0, atol=SAME_POSE):
            return request.T_world_cam  # the window has the anchor where the front end does: the sequential order
        correction = found[0].compose(gtsam.Pose3(T_front).inverse())
        return correction.compose(request.T_world_cam)

    def optimize(self) -> WindowUpdate | None:
        """Optimise the window; None when it had nothing to optimise (fewer than two keyframes, no
        target). When the rig offset's ``delta_x`` is released in this optimisation, the window's
        depths are searched again and the window optimised once more; the update then says how
        the frames tracked against its keyframes scale."""
        window = self.window
        solver = self.config.solver.window
        rig = window.rig
        x_was_estimated = rig is not None and rig.x_estimated
        held_depths = ({w.index: w.inverse_depth.copy() for w in window.keyframes}
                       if rig is not None and not x_was_estimated else None)
        res = window.optimize(solver)
        scales = None
        if rig is not None and rig.x_estimated and not x_was_estimated:
            assert held_depths is not None
            self._research_window_depths(rig)
            res = window.optimize(solver) or res
            scales = {w.index: tracked_translation_scale(held_depths[w.index], w.inverse_depth)
                      for w in window.keyframes
                      if w.index in held_depths and held_depths[w.index].shape == w.inverse_depth.shape}
        if res is None:
            return None
        members = [WindowMember(w.index, w.pose, w.inverse_depth.copy(),
                                None if w.right is None else w.stereo_affine.copy()) for w in window.keyframes]
        return WindowUpdate(members, res, window.observation_counts(), scales, rig)

    def _research_window_depths(self, rig: RigOffset) -> None:
        """Once the window releases ``delta_x`` (docs/window.md, "Rig calibration"), its keyframes'
        depths, initialised with the right image corrected by the offset known then, are searched
        again against the right image corrected by the estimate (and their stereo affine fitted
        again): a point whose new search matches takes its inverse depth and variance."""
        assert isinstance(self.camera, StereoCamera)
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
