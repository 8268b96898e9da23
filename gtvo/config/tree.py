"""The tree of a run's settings: :class:`OdometryConfig` and the sections it nests (the tree and
its keys: :mod:`gtvo.config`, docs/configuration.md)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from factors.params import PhotometricConfig
from gtvo.config.sections.flow_fallback import FlowPoseConfig
from gtvo.config.sections.frame_checks import FrameCheckConfig
from gtvo.config.sections.frontend import (MIN_POINTS_PER_KEYFRAME, FrontendConfig, PointSelectionConfig,
                                           StereoSearchConfig)
from gtvo.config.sections.imu import ImuConfig
from gtvo.config.sections.keyframes import KeyframeConfig
from gtvo.config.sections.loops import LoopClosureConfig
from gtvo.config.sections.motion import MotionModelConfig, MotionNoiseConfig
from gtvo.config.sections.refine import RefineConfig
from gtvo.config.sections.solver import SolverConfig
from gtvo.config.sections.tracking import TrackingConfig
from gtvo.config.sections.wheel import WheelConfig
from gtvo.config.sections.window import WindowConfig
from gtvo.core.settings import check_nested

ModeName = Literal["track", "window"]

__all__ = ["MIN_POINTS_PER_KEYFRAME", "FlowPoseConfig", "FrameCheckConfig", "FrontendConfig", "ImuConfig", "KeyframeConfig",
           "LoopClosureConfig", "MotionModelConfig", "MotionNoiseConfig", "OdometryConfig", "PhotometricConfig",
           "PointSelectionConfig", "RefineConfig", "SolverConfig", "StereoSearchConfig", "TrackingConfig",
           "WheelConfig", "WindowConfig"]


@dataclass(frozen=True)
class OdometryConfig:
    """Every setting of a VO run (the tree in the module doc; defaults suit KITTI-like and indoor data).

    ``solver`` and ``motion_model`` also take a name: ``solver="handrolled"`` is the solver of both
    the tracker and the window, as the command line's ``--solver handrolled``
    (:meth:`SolverConfig.both`; ``SolverConfig(tracker=..., window=...)`` mixes them),
    ``motion_model="kalman"`` is ``MotionModelConfig(model="kalman")``.

    Attributes:
        mode: ``window``: every new keyframe joins a sliding window of keyframes whose poses, affine
            brightness and inverse depths are optimised jointly (:mod:`gtvo.window`; later frames are
            tracked against the optimised keyframe); ``track``: frame-to-keyframe tracking only.
        solver: the solvers of the tracker and of the window (a solver name sets both, as --solver does).
        frontend: point selection and stereo / RGB-D depths of new keyframes.
        keyframes: the rule that makes a tracked frame a keyframe.
        tracking: the coarse-to-fine tracker (its photometric model is ``photometric``).
        window: the sliding window (its photometric model is ``photometric``).
        flow_fallback: when tracking fails from every motion-model guess, try once more from a guess
            of sparse optical flow + PnP (:func:`gtvo.frontend.flow_pose.optical_flow_pose`) before
            declaring the frame lost; null turns it off.
        frame_checks: when a frame is *frozen* (its image repeats the previous one's while the rig
            moves) or a tracked frame *suspect* (its image contradicts a motion model that has been
            right: an out-of-order frame; :mod:`gtvo.frontend.frame_checks`).
        motion_model: the initial guess of each frame's pose.
        photometric: the photometric model shared by the tracker, the window and the stereo gain
            estimate: noise, Huber threshold, pattern and the sensor's clipped range.
        loops: loop closing after the run: whether it runs (gtvo run --loop-closure), place
            recognition and the verification of a loop (gtvo.loops, docs/loop_closure.md).
        wheel: a ground robot's wheel odometry, when the sequence has it: the calibration model, the
            base-to-camera transform and how readings become metres (docs/wheel_odometry.md).
        imu: an IMU beside the images, when the log has one: whether it is used, what its files do
            not say (noise model, pose on the camera, clock offset) and how readings are checked
            (docs/imu.md).
        refine: the whole-log refinement after the window pass (and loop closing): one graph over
            every keyframe, then the non-keyframes re-placed (gtvo.refinement, docs/refinement.md).
    """

    mode: ModeName = "window"
    solver: SolverConfig = field(default_factory=SolverConfig)
    frontend: FrontendConfig = field(default_factory=FrontendConfig)
    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    window: WindowConfig = field(default_factory=WindowConfig)
    flow_fallback: FlowPoseConfig | None = field(default_factory=FlowPoseConfig)
    frame_checks: FrameCheckConfig = field(default_factory=FrameCheckConfig)
    motion_model: MotionModelConfig = field(default_factory=MotionModelConfig)
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)
    loops: LoopClosureConfig = field(default_factory=LoopClosureConfig)
    wheel: WheelConfig = field(default_factory=WheelConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)

    def __post_init__(self) -> None:
        if isinstance(self.solver, str):
            object.__setattr__(self, "solver", SolverConfig.from_name(self.solver))
        if isinstance(self.motion_model, str):
            object.__setattr__(self, "motion_model", MotionModelConfig.from_name(self.motion_model))
        check_nested(self)

