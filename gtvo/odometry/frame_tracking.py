"""Tracking a frame against the latest keyframe, from several guesses (the odometry's step 3).

:class:`FrameTracker` tries the motion model's guess, "no motion since the last frame" and "at
the keyframe" (:func:`gtvo.frontend.tracking.track_with_guesses`, hand-rolled or GTSAM solver), and
when all fail, a guess from the points' sparse optical flow and PnP (``config.flow_fallback``,
:func:`gtvo.frontend.optical_flow_pose`). A frame tracked from the flow guess is *recovered*.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.photometric import GradientImage
from gtvo.config import OdometryConfig
from gtvo.core.camera import PinholeCamera
from gtvo.core.timing import stage, timed
from gtvo.frontend import optical_flow_pose
from gtvo.frontend.tracking import TrackingKeyframe, TrackingResult, frame_pyramid, track_gtsam, track_handrolled, track_with_guesses
from gtvo.odometry.estimates import Keyframe, rigid_pose


@dataclass
class Track:
    """One frame's tracking against a keyframe.

    Attributes:
        result: the tracker's result (successful or not, with the reason).
        against: the keyframe's tracking data it was tracked against.
        target: the frame's full-resolution image with gradients (with ``against``: what
            :func:`gtvo.frontend.tracking.point_residuals` needs for the residuals at the result).
        flow_reason: when the optical-flow guess tracked the frame, why (the motion model's
            failure); None otherwise.
    """

    result: TrackingResult
    against: TrackingKeyframe
    target: GradientImage
    flow_reason: str | None = None


class FrameTracker:
    """Tracks frames against the latest keyframe (module docstring).

    Args:
        config: the run's settings (tracker solver, motion model's acceptance, flow fallback,
            photometric clip range).
        camera: the left camera.

    Attributes:
        flow_recoveries: frames that failed from every motion-model guess and were tracked from
            the optical-flow guess.
    """

    def __init__(self, config: OdometryConfig, camera: PinholeCamera) -> None:
        self.config = config
        self.camera = camera
        self.flow_recoveries = 0

    def pyramid(self, left: NDArray[np.float32], kf: Keyframe) -> list[GradientImage]:
        """The frame's image pyramid with gradients, as deep as ``kf``'s tracker."""
        assert kf.tracker is not None  # the latest keyframe keeps its tracker
        with stage("tracking", absorb=True):
            return frame_pyramid(left, kf.tracker.levels, self.config.photometric.clip_range)

    @timed("tracking", absorb=True)
    def track(self, kf: Keyframe, pyramid: list[GradientImage], T_pred: gtsam.Pose3, last: gtsam.Pose3,
              left: NDArray[np.float32], affine: NDArray[np.float64], prev_rms: float | None) -> Track:
        """Track the frame (``pyramid``, ``left``) against ``kf`` from the prediction ``T_pred``, the
        last good pose ``last`` and the keyframe's own pose, starting at brightness ``affine``; a
        guess whose whitened RMS is within ``motion_model.accept_rms_factor`` of ``prev_rms`` is
        taken at once. When all fail, from the optical-flow guess."""
        assert kf.tracker is not None
        guesses = [kf.T_world_cam.between(T_pred), kf.T_world_cam.between(last), gtsam.Pose3()]
        solver = track_handrolled if self.config.solver.tracker == "handrolled" else track_gtsam
        factor = self.config.motion_model.accept_rms_factor
        result = track_with_guesses(kf.tracker, pyramid, guesses, affine, solver=solver,
                                    accept_rms=0.0 if prev_rms is None else factor * prev_rms)
        if result.success or self.config.flow_fallback is None or kf.image is None:
            return Track(result, kf.tracker, pyramid[0])
        flow = optical_flow_pose(self.camera, kf.image, kf.points.pixels, kf.points.inverse_depth, left,
                                 self.config.flow_fallback)
        if flow is None:
            result.reason = f"{result.reason}; no optical-flow guess"
            return Track(result, kf.tracker, pyramid[0])
        retry = solver(kf.tracker, pyramid, rigid_pose(flow.T_keyframe_frame), affine)
        if retry.success:
            self.flow_recoveries += 1
            return Track(retry, kf.tracker, pyramid[0],
                         f"tracked from the optical-flow guess (from the motion model: {result.reason})")
        result.reason = f"{result.reason}; from the optical-flow guess: {retry.reason}"
        return Track(result, kf.tracker, pyramid[0])
