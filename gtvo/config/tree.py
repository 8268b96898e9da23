"""The tree of a run's settings: :class:`OdometryConfig` and the sections it nests (the tree and
its keys: :mod:`gtvo.config`, docs/configuration.md)."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import types
import typing
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from factors.params import PhotometricConfig
from gtvo.core.settings import SettingError, check_settings, setting, type_hints
from gtvo.frontend.flow_pose import FlowPoseConfig
from gtvo.frontend.frame_checks import FrameCheckConfig
from gtvo.frontend.keyframes import KeyframeConfig
from gtvo.frontend.point_selection import PointSelectionConfig
from gtvo.frontend.rgbd import DEPTH_SIGMA_MODEL
from gtvo.frontend.stereo_depth import StereoSearchConfig
from gtvo.frontend.tracking import TrackingConfig
from gtvo.motion.model import INITIAL_RATE_SIGMAS, MotionNoiseConfig
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

    points_per_keyframe: int = setting(300, f">= {MIN_POINTS_PER_KEYFRAME}")
    points: PointSelectionConfig = field(default_factory=PointSelectionConfig)
    stereo: StereoSearchConfig = field(default_factory=StereoSearchConfig)
    depth_sigma_model: tuple[float, float] = setting(DEPTH_SIGMA_MODEL, ">= 0")

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
    accept_rms_factor: float = setting(1.1, ">= 0")
    kalman_noise: MotionNoiseConfig = field(default_factory=MotionNoiseConfig)
    kalman_initial_rate_sigmas: tuple[float, float, float] = setting(INITIAL_RATE_SIGMAS, "> 0")

    def __post_init__(self) -> None:
        _check_nested(self)

    @classmethod
    def from_name(cls, name: str) -> "MotionModelConfig":
        """The model ``name`` with the default settings (``motion_model="kalman"``)."""
        return cls(model=name)  # type: ignore[arg-type]


@dataclass(frozen=True)
class OdometryConfig:
    """Every setting of a VO run (the tree in the module doc; defaults suit KITTI-like and indoor data).

    ``solver`` and ``motion_model`` also take a name, as before the tree: ``solver="gtsam"`` is the
    tracker's solver (``SolverConfig(tracker="gtsam")``; the window keeps its own, GTSAM by
    default; ``SolverConfig.both(name)`` is the CLI's ``--solver``), ``motion_model="kalman"`` is
    ``MotionModelConfig(model="kalman")``. The flat names of the settings before the tree
    (:data:`LEGACY_NAMES`, e.g. ``points_per_keyframe``) are accepted by the constructor and read
    as attributes, each the alias of its key; config files use the keys.

    Attributes:
        mode: ``window``: every new keyframe joins a sliding window of keyframes whose poses, affine
            brightness and inverse depths are optimised jointly (:mod:`gtvo.window`; later frames are
            tracked against the optimised keyframe); ``track``: frame-to-keyframe tracking only.
        solver: the solvers of the tracker and of the window.
        frontend: point selection and stereo / RGB-D depths of new keyframes.
        keyframes: the rule that makes a tracked frame a keyframe.
        tracking: the coarse-to-fine tracker (its photometric settings come from ``photometric``).
        window: the sliding window (its photometric settings come from ``photometric``).
        flow_fallback: when tracking fails from every motion-model guess, try once more from a guess
            of sparse optical flow + PnP (:func:`gtvo.frontend.flow_pose.optical_flow_pose`) before
            declaring the frame lost; null turns it off.
        frame_checks: when a tracked frame is *suspect* (its image contradicts a motion model that
            has been right: a duplicated or out-of-order frame; :mod:`gtvo.frontend.frame_checks`).
        motion_model: the initial guess of each frame's pose.
        photometric: the photometric model shared by the tracker, the window and the stereo gain
            estimate: noise, Huber threshold, pattern and the sensor's clipped range.
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

    def __post_init__(self) -> None:
        if isinstance(self.solver, str):
            object.__setattr__(self, "solver", SolverConfig(tracker=self.solver))  # type: ignore[arg-type]
        if isinstance(self.motion_model, str):
            object.__setattr__(self, "motion_model", MotionModelConfig.from_name(self.motion_model))
        _check_nested(self)
        for name, keys in PHOTOMETRIC_COPIES.items():
            object.__setattr__(self, name, _with_photometric(name, getattr(self, name), keys, self.photometric))


#: The settings of ``tracking`` and ``window`` that ``photometric`` sets (not keys of a config file).
PHOTOMETRIC_COPIES: dict[str, tuple[str, ...]] = {
    "tracking": ("sigma_intensity", "huber_k", "pattern", "clip_range"),
    "window": ("sigma_intensity", "huber_k", "pattern"),
}
_DERIVED = frozenset(f"{name}.{key}" for name, keys in PHOTOMETRIC_COPIES.items() for key in keys)

#: The flat names of the settings before the tree, each the alias of one key: accepted by
#: ``OdometryConfig(...)`` and readable as attributes (``config.points_per_keyframe``), so code
#: written against the flat config keeps working; config files use the keys.
LEGACY_NAMES: dict[str, str] = {
    "points_per_keyframe": "frontend.points_per_keyframe",
    "max_disparity": "frontend.stereo.max_disparity",
    "depth_sigma_model": "frontend.depth_sigma_model",
    "keyframe_min_visible": "keyframes.min_visible",
    "keyframe_max_motion": "keyframes.max_motion",
    "keyframe_max_flow": "keyframes.max_flow",
    "keyframe_max_rotation_deg": "keyframes.max_rotation_deg",
    "keyframe_max_brightness": "keyframes.max_brightness",
    "accept_rms_factor": "motion_model.accept_rms_factor",
    "window_solver": "solver.window",
}


def _accept_legacy_names(init: Any) -> Any:
    """``OdometryConfig.__init__`` that also takes :data:`LEGACY_NAMES` as keywords."""

    @functools.wraps(init)
    def __init__(self: OdometryConfig, *args: Any, **kwargs: Any) -> None:
        legacy = {k: kwargs.pop(k) for k in list(kwargs) if k in LEGACY_NAMES}
        init(self, *args, **kwargs)
        if legacy:
            resolved: Any = self
            for name, value in legacy.items():
                try:
                    resolved = _replaced(resolved, LEGACY_NAMES[name].split("."), value)
                except SettingError as exc:
                    raise SettingError(LEGACY_NAMES[name], exc.detail) from None
            for f in dataclasses.fields(self):
                object.__setattr__(self, f.name, getattr(resolved, f.name))

    return __init__


def _replaced(obj: Any, path: list[str], value: Any) -> Any:
    """``obj`` with the setting at ``path`` (its field names) replaced by ``value``."""
    head, *rest = path
    return dataclasses.replace(obj, **{head: _replaced(getattr(obj, head), rest, value) if rest else value})


def _legacy_property(key: str) -> property:
    def get(self: OdometryConfig) -> Any:
        value: Any = self
        for part in key.split("."):
            value = getattr(value, part)
        return value

    return property(get, doc=f"The value of ``{key}`` (its flat name before the configuration tree).")


OdometryConfig.__init__ = _accept_legacy_names(OdometryConfig.__init__)  # type: ignore[method-assign]
for _name, _key in LEGACY_NAMES.items():
    setattr(OdometryConfig, _name, _legacy_property(_key))


def _check_nested(obj: Any) -> None:
    """:func:`check_settings` plus: every nested-config field holds its config class (or None
    where allowed), so a wrong object fails here, naming the field, not deep in a run."""
    check_settings(obj)
    hints = type_hints(type(obj))
    for f in dataclasses.fields(obj):
        cls, value = _dataclass_of(hints[f.name]), getattr(obj, f.name)
        if cls is not None and not isinstance(value, cls) and not (value is None and _optional(hints[f.name])):
            raise SettingError(f.name, f"must be a {cls.__name__}, got {value!r}")


def _with_photometric(name: str, sub: Any, keys: tuple[str, ...], params: PhotometricConfig) -> Any:
    """``sub`` with its photometric ``keys`` taken from ``params``. A value the caller set on
    ``sub`` (not a copy made here: ``dataclasses.replace(config, photometric=...)`` re-copies)
    that differs from both its default and ``params`` is an error: two sources for one setting."""
    values = {k: params.pattern_array if k == "pattern" else getattr(params, k) for k in keys}
    if not getattr(sub, "_photometric_copy", False):
        default = type(sub)()
        for k in keys:
            have = getattr(sub, k)
            if not _same(have, getattr(default, k)) and not _same(have, values[k]):
                raise SettingError(f"{name}.{k}", f"is set by photometric.{k}; set it there")
    copy = dataclasses.replace(sub, **values)
    object.__setattr__(copy, "_photometric_copy", True)
    return copy


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return a is not None and b is not None and np.array_equal(np.asarray(a, float), np.asarray(b, float))
    return bool(a == b)


def _optional(hint: Any) -> bool:
    return type(None) in typing.get_args(hint) and typing.get_origin(hint) in (typing.Union, types.UnionType)


def _dataclass_of(hint: Any) -> type | None:
    """The dataclass of a ``Config`` or ``Config | None`` hint, else None."""
    for h in (hint, *typing.get_args(hint)):
        if inspect.isclass(h) and dataclasses.is_dataclass(h):
            return h
    return None
