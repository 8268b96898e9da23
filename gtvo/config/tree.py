"""The tree of a run's settings: :class:`OdometryConfig` and the sections it nests (the tree and
its keys: :mod:`gtvo.config`, docs/configuration.md)."""

from __future__ import annotations

import dataclasses
import inspect
import types
import typing
from dataclasses import dataclass, field
from typing import Any, Literal


from factors.params import PhotometricConfig
from gtvo.config.imu import ImuConfig
from gtvo.config.wheel import WheelConfig
from gtvo.core.settings import SettingError, check_settings, setting, type_hints
from gtvo.frontend.flow_pose import FlowPoseConfig
from gtvo.frontend.frame_checks import FrameCheckConfig
from gtvo.frontend.keyframes import KeyframeConfig
from gtvo.frontend.point_selection import PointSelectionConfig
from gtvo.frontend.rgbd import DEPTH_SIGMA_MODEL
from gtvo.frontend.stereo_depth import StereoSearchConfig
from gtvo.frontend.tracking import TrackingConfig
from gtvo.loops.config import LoopClosureConfig
from gtvo.motion.model import INITIAL_RATE_SIGMAS, MotionNoiseConfig
from gtvo.refinement.config import RefineConfig
from gtvo.window import WindowConfig

SolverName = Literal["handrolled", "gtsam"]
MotionModelName = Literal["constant-velocity", "kalman"]
ModeName = Literal["track", "window"]

#: The fewest points per keyframe :class:`OdometryConfig` accepts.
MIN_POINTS_PER_KEYFRAME = 50


@dataclass(frozen=True)
class SolverConfig:
    """Which solver runs each optimisation.

    Attributes:
        tracker: the frame tracker's: ``handrolled`` (vectorised LM, the notes' Algorithm 3) or ``gtsam``.
        window: the sliding window's: ``gtsam`` (LM on smart factors, the window's engine) or ``handrolled``.
    """

    tracker: SolverName = "handrolled"
    window: SolverName = "gtsam"

    def __post_init__(self) -> None:
        check_settings(self)

    @classmethod
    def both(cls, name: str) -> "SolverConfig":
        """One solver for the tracker and the window (the CLI's ``--solver``)."""
        return cls(tracker=name, window=name)  # type: ignore[arg-type]

    @classmethod
    def from_name(cls, name: str) -> "SolverConfig":
        """A solver name means both solvers, as ``--solver NAME`` (``OdometryConfig(solver="gtsam")``,
        ``solver: gtsam`` in a config file); :meth:`both`."""
        return cls.both(name)


@dataclass(frozen=True)
class FrontendConfig:
    """How a keyframe gets its points and their inverse depths.

    Attributes:
        points_per_keyframe: target number of selected points per keyframe (300: DSO's density of
            2000 active points in a 7-keyframe window; stereo keeps about 60 % of them on KITTI).
            The tracker and the window use the same points; more were measured to be slower and
            no more accurate (docs/benchmarks.md, "Point density").
        points: the point selection (:func:`gtvo.frontend.select_points`).
        stereo: the stereo search (:func:`gtvo.frontend.stereo_inverse_depth`).
        depth_sigma_model: RGB-D only: ``(s0, s2)`` of the depth noise ``sigma_z = s0 + s2 z^2`` (m;
            :func:`gtvo.frontend.rgbd.rgbd_keyframe_points`).
    """

    points_per_keyframe: int = setting(300, f"[{MIN_POINTS_PER_KEYFRAME}, 100000]")
    points: PointSelectionConfig = field(default_factory=PointSelectionConfig)
    stereo: StereoSearchConfig = field(default_factory=StereoSearchConfig)
    depth_sigma_model: tuple[float, float] = setting(DEPTH_SIGMA_MODEL, "[0, 1]")

    def __post_init__(self) -> None:
        _check_nested(self)


@dataclass(frozen=True)
class MotionModelConfig:
    """The initial guesses of each frame's pose.

    Attributes:
        model: ``constant-velocity`` or ``kalman`` (the constant-acceleration filter of :mod:`gtvo.motion.model`).
        accept_rms_factor: tracking tries the motion model's guess first and accepts it at once when
            its whitened RMS is below this factor times the previous frame's; otherwise it also tries
            "no motion" and "keyframe pose" and keeps the lowest-cost success (0: always try all).
        kalman_noise: the Kalman filter's acceleration and measurement noise (``model: kalman``).
        kalman_initial_rate_sigmas: the Kalman filter's initial rate uncertainty ``(dX, dZ, dtheta)``
            (m/s, m/s, rad/s).
    """

    model: MotionModelName = "constant-velocity"
    accept_rms_factor: float = setting(1.1, "[0, 100]")
    kalman_noise: MotionNoiseConfig = field(default_factory=MotionNoiseConfig)
    kalman_initial_rate_sigmas: tuple[float, float, float] = setting(INITIAL_RATE_SIGMAS, "[1e-6, 1000]")

    def __post_init__(self) -> None:
        _check_nested(self)

    @classmethod
    def from_name(cls, name: str) -> "MotionModelConfig":
        """The model ``name`` with the default settings (``motion_model="kalman"``)."""
        return cls(model=name)  # type: ignore[arg-type]


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
        frame_checks: when a tracked frame is *suspect* (its image contradicts a motion model that
            has been right: a duplicated or out-of-order frame; :mod:`gtvo.frontend.frame_checks`).
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
        _check_nested(self)


def _check_nested(obj: Any) -> None:
    """:func:`check_settings` plus: every nested-config field holds its config class (or None
    where allowed), so a wrong object fails here, naming the field, not deep in a run."""
    check_settings(obj)
    hints = type_hints(type(obj))
    for f in dataclasses.fields(obj):
        cls, value = _dataclass_of(hints[f.name]), getattr(obj, f.name)
        if cls is not None and not isinstance(value, cls) and not (value is None and _optional(hints[f.name])):
            raise SettingError(f.name, f"must be a {cls.__name__}, got {value!r}")


def _optional(hint: Any) -> bool:
    return type(None) in typing.get_args(hint) and typing.get_origin(hint) in (typing.Union, types.UnionType)


def _dataclass_of(hint: Any) -> type | None:
    """The dataclass of a ``Config`` or ``Config | None`` hint, else None."""
    for h in (hint, *typing.get_args(hint)):
        if inspect.isclass(h) and dataclasses.is_dataclass(h):
            return h
    return None
