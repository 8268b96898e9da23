"""The configuration tree of a VO run: :class:`OdometryConfig` and the settings it nests.

One place for every setting of a run (KISS-ICP's single config): the front end, the tracker
(:class:`gtvo.frontend.tracking.TrackingConfig`), the sliding window
(:class:`gtvo.window.WindowConfig`) and the optical-flow fallback
(:class:`gtvo.frontend.flow_pose.FlowPoseConfig`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from gtvo.errors import InputError
from gtvo.frontend import FlowPoseConfig
from gtvo.frontend.tracking import TrackingConfig
from gtvo.window import WindowConfig

SolverName = Literal["handrolled", "gtsam"]
MotionModelName = Literal["constant-velocity", "kalman"]
ModeName = Literal["track", "window"]


#: The fewest points per keyframe :class:`OdometryConfig` accepts.
MIN_POINTS_PER_KEYFRAME = 50


@dataclass(frozen=True)
class OdometryConfig:
    """Settings of the VO front end.

    Attributes:
        solver: ``"handrolled"`` (vectorised LM, the notes' Algorithm 3) or ``"gtsam"``.
        points_per_keyframe: target number of selected points per keyframe (300: DSO's density
            of 2000 active points in a 7-keyframe window; stereo keeps about 60 % of them on KITTI).
            The tracker and the window use the same points; more points were measured to be
            slower and no more accurate (docs/benchmarks.md, "Point density").
        tracking: the tracker's settings.
        keyframe_min_visible: make a new keyframe when fewer than this fraction of the keyframe's
            points are still tracked (valid residuals).
        keyframe_max_flow: make a new keyframe when the RMS optical flow that the translation
            since the keyframe causes at its points exceeds this fraction of ``width + height``
            (DSO's rule: its translation weight 0.04 (640 + 480) = 44.8 gives 25 px at VGA).
        keyframe_max_motion: make a new keyframe when ``|t_keyframe_frame| * median(d)`` (the
            translation relative to the median scene depth, i.e. about the mean optical-flow
            angle caused by translation) exceeds this.
        keyframe_max_rotation_deg: ... or the rotation since the keyframe exceeds this.
        keyframe_max_brightness: ... or ``|a_frame - a_keyframe|`` (log gain) exceeds this.
        max_disparity: largest disparity (px) searched by the stereo initialisation.
        depth_sigma_model: for RGB-D: ``(s0, s2)`` of the depth noise ``sigma_z = s0 + s2 z^2``.
        motion_model: initial guess of each frame: ``"constant-velocity"`` or ``"kalman"``.
        accept_rms_factor: tracking tries the motion-model guess first and accepts it at once
            when its whitened RMS is below this factor times the previous frame's; otherwise it
            also tries "no motion" and "keyframe pose" and keeps the lowest-cost success
            (0 = always try all).
        mode: ``"track"`` (frame-to-keyframe tracking only) or ``"window"`` (every new keyframe
            joins a sliding window of keyframes whose poses, affine brightness and inverse depths
            are optimised jointly, :mod:`gtvo.window`; later frames are tracked against the
            optimised keyframe with its optimised depths).
        window_solver: the window's solver, ``"gtsam"`` (LM on smart factors) or ``"handrolled"``.
        window: the window's settings (size, weights, priors, iterations).
        flow_fallback: when tracking fails from every motion-model guess (first frames, after a
            re-initialisation, an abrupt change of speed), try once more from a guess of sparse
            optical flow + PnP (:func:`gtvo.frontend.flow_pose.optical_flow_pose`) before
            declaring the frame lost; None turns it off.
    """

    solver: SolverName = "handrolled"
    points_per_keyframe: int = 300
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    keyframe_min_visible: float = 0.7
    keyframe_max_motion: float = 0.3
    keyframe_max_flow: float = 1.0 / 44.8
    keyframe_max_rotation_deg: float = 8.0
    keyframe_max_brightness: float = 0.3
    max_disparity: int = 128
    depth_sigma_model: tuple[float, float] = (0.0012, 0.0019)
    motion_model: MotionModelName = "constant-velocity"
    accept_rms_factor: float = 1.1
    mode: ModeName = "window"
    window_solver: SolverName = "gtsam"
    window: WindowConfig = field(default_factory=WindowConfig)
    flow_fallback: FlowPoseConfig | None = field(default_factory=FlowPoseConfig)

    def __post_init__(self) -> None:
        if self.solver not in ("handrolled", "gtsam"):
            raise InputError(f"unknown solver {self.solver!r}: use 'handrolled' or 'gtsam'")
        if self.points_per_keyframe < MIN_POINTS_PER_KEYFRAME:
            raise InputError(f"points per keyframe must be >= {MIN_POINTS_PER_KEYFRAME}, got {self.points_per_keyframe}")
        if self.motion_model not in ("constant-velocity", "kalman"):
            raise InputError(f"unknown motion model {self.motion_model!r}")
        if self.mode not in ("track", "window"):
            raise InputError(f"unknown mode {self.mode!r}: use 'track' or 'window'")
        if self.window_solver not in ("handrolled", "gtsam"):
            raise InputError(f"unknown window solver {self.window_solver!r}: use 'handrolled' or 'gtsam'")
