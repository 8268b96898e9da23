"""The configuration tree of a VO run: :class:`OdometryConfig` and the settings it nests.

One place for every setting of a run (KISS-ICP's single config), one frozen dataclass per
component, each field's default and allowed range declared once beside it
(:func:`gtvo.core.settings.setting`)::

    OdometryConfig
      mode                 "window" | "track"
      solver               SolverConfig (tracker, window)
      frontend             FrontendConfig (points_per_keyframe, points: PointSelectionConfig,
                                           stereo: StereoSearchConfig, depth_sigma_model)
      keyframes            gtvo.frontend.keyframes.KeyframeRule
      tracking             gtvo.frontend.tracking.TrackingConfig
      window               gtvo.window.WindowConfig
      flow_fallback        gtvo.frontend.flow_pose.FlowPoseConfig | None
      motion_model         MotionModelConfig
      photometric          factors.params.PhotometricParams

The photometric model (noise, Huber threshold, pattern, clipped range) is set once, in
``photometric``; the tracker's and the window's copies of it are filled from there (and are not
keys of their own in a config file). The command line and the library share these defaults:
``gtvo run`` and :func:`gtvo.run` run the same solvers.

A run's configuration as plain data: :func:`config_to_dict` / :func:`config_from_dict` (the
inverse, checking every key, type and range), :func:`config_to_yaml` and :func:`load_config`
(a YAML or JSON file; ``gtvo run --config FILE``). The list of every key: docs/configuration.md
(:func:`config_reference` writes it).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import inspect
import math
import re
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from factors.params import PhotometricParams
from gtvo.core.settings import SettingError, check_settings, setting, type_hints
from gtvo.errors import InputError
from gtvo.frontend.flow_pose import FlowPoseConfig
from gtvo.frontend.keyframes import KeyframeRule
from gtvo.frontend.point_selection import PointSelectionConfig
from gtvo.frontend.rgbd import DEPTH_SIGMA_MODEL
from gtvo.frontend.stereo_depth import StereoSearchConfig
from gtvo.frontend.tracking import TrackingConfig
from gtvo.motion.model import INITIAL_RATE_SIGMAS, MotionNoise
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
    kalman_noise: MotionNoise = field(default_factory=MotionNoise)
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
        motion_model: the initial guess of each frame's pose.
        photometric: the photometric model shared by the tracker, the window and the stereo gain
            estimate: noise, Huber threshold, pattern and the sensor's clipped range.
    """

    mode: ModeName = "window"
    solver: SolverConfig = field(default_factory=SolverConfig)
    frontend: FrontendConfig = field(default_factory=FrontendConfig)
    keyframes: KeyframeRule = field(default_factory=KeyframeRule)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    window: WindowConfig = field(default_factory=WindowConfig)
    flow_fallback: FlowPoseConfig | None = field(default_factory=FlowPoseConfig)
    motion_model: MotionModelConfig = field(default_factory=MotionModelConfig)
    photometric: PhotometricParams = field(default_factory=PhotometricParams)

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
            tree: dict[str, Any] = {}
            for name, value in legacy.items():
                *parents, last = LEGACY_NAMES[name].split(".")
                node = tree
                for part in parents:
                    node = node.setdefault(part, {})
                node[last] = list(value) if isinstance(value, tuple) else value
            resolved = config_from_dict(tree, base=self)
            for f in dataclasses.fields(self):
                object.__setattr__(self, f.name, getattr(resolved, f.name))

    return __init__


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


def _with_photometric(name: str, sub: Any, keys: tuple[str, ...], params: PhotometricParams) -> Any:
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


# -- plain data ------------------------------------------------------------------------------------
def config_to_dict(config: OdometryConfig) -> dict[str, Any]:
    """The whole tree as plain JSON/YAML data (dicts, lists, str, numbers, bools, None); infinite
    floats are the strings ``"inf"`` / ``"-inf"``. :func:`config_from_dict` inverts it exactly."""
    return _to_plain(config, "")


def _to_plain(obj: Any, path: str) -> Any:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _to_plain(getattr(obj, f.name), _join(path, f.name)) for f in dataclasses.fields(obj)
                if _join(path, f.name) not in _DERIVED}
    if isinstance(obj, np.ndarray):
        return _to_plain(obj.tolist(), path)
    if isinstance(obj, (list, tuple)):
        return [_to_plain(v, path) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return "nan" if math.isnan(obj) else ("inf" if obj > 0 else "-inf")
    return obj


class ConfigKeyError(InputError):
    """A bad key or value in a configuration: ``key`` (dotted), ``detail`` (what is wrong)."""

    def __init__(self, key: str, detail: str, source: str | Path | None = None) -> None:
        where = f"{source}: " if source is not None else ""
        super().__init__(f"{where}key '{key}': {detail}")
        self.key, self.detail = key, detail


def config_from_dict(data: Any, source: str | Path | None = None,
                     base: OdometryConfig | None = None) -> OdometryConfig:
    """An :class:`OdometryConfig` from plain data: a partial tree, whose missing keys keep the
    values of ``base`` (default: the defaults).

    Raises:
        ConfigKeyError: an :class:`InputError`, one line ``"SOURCE: key 'window.size': must be >= 2,
            got 1"``, for an unknown key, a value of the wrong type or out of its range.
    """
    if data is None:
        data = {}
    if base is not None and isinstance(data, dict):
        data = _merged(config_to_dict(base), data)
    try:
        return _build(OdometryConfig, data, "")
    except SettingError as exc:
        raise ConfigKeyError(exc.key, exc.detail, source) from None


def _merged(base: dict[str, Any], data: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``data``'s keys put in, section by section."""
    out = dict(base)
    for k, v in data.items():
        out[k] = _merged(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _build(cls: type, data: Any, path: str) -> Any:
    if isinstance(data, str) and hasattr(cls, "from_name"):
        try:
            return cls.from_name(data)
        except SettingError as exc:
            raise SettingError(path, exc.detail) from None
    if not isinstance(data, dict):
        raise SettingError(path or "(top level)", f"must be a mapping of keys, got {_show(data)}")
    hints = type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls) if _join(path, f.name) not in _DERIVED]
    for key in data:
        if _join(path, str(key)) in _DERIVED:
            raise SettingError(_join(path, str(key)), f"is set by photometric.{key}; set it there")
        if key not in names:
            close = difflib.get_close_matches(str(key), names, n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else f"; known: {', '.join(names)}"
            raise SettingError(_join(path, str(key)), f"unknown key{hint}")
    kwargs = {k: _convert(hints[k], v, _join(path, k)) for k, v in data.items()}
    try:
        return cls(**kwargs)
    except SettingError as exc:
        raise SettingError(_join(path, exc.key), exc.detail) from None
    except InputError as exc:
        raise SettingError(path or "(top level)", str(exc)) from None


def _optional(hint: Any) -> bool:
    return type(None) in typing.get_args(hint) and typing.get_origin(hint) in (typing.Union, types.UnionType)


def _dataclass_of(hint: Any) -> type | None:
    """The dataclass of a ``Config`` or ``Config | None`` hint, else None."""
    for h in (hint, *typing.get_args(hint)):
        if inspect.isclass(h) and dataclasses.is_dataclass(h):
            return h
    return None


def _convert(hint: Any, value: Any, key: str) -> Any:
    """``value`` checked (and converted) against the type ``hint`` of ``key``."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _convert(inner[0], value, key) if len(inner) == 1 else value
    if dataclasses.is_dataclass(hint):
        return _build(hint, value, key)
    if origin is Literal:
        return value  # the choices are checked by the dataclass (check_settings), naming the key
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise SettingError(key, f"must be a list, got {_show(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, key) for v in value)
        if len(value) != len(args):
            raise SettingError(key, f"must be a list of {len(args)}, got {_show(value)}")
        return tuple(_convert(a, v, key) for a, v in zip(args, value))
    if hint is bool:
        if not isinstance(value, bool):
            raise SettingError(key, f"must be true or false, got {_show(value)}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SettingError(key, f"must be an integer, got {_show(value)}")
        return value
    if hint is float:
        if isinstance(value, str) and re.fullmatch(r"[+-]?(inf|\.inf|infinity)", value.strip().lower()):
            return -math.inf if value.strip().startswith("-") else math.inf
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SettingError(key, f"must be a number, got {_show(value)}")
        return float(value)
    if hint is str and not isinstance(value, str):
        raise SettingError(key, f"must be a string, got {_show(value)}")
    return value


def _show(value: Any) -> str:
    text = repr(value)
    return f"{text if len(text) <= 40 else text[:37] + '...'} ({type(value).__name__})"


def as_config(value: "OdometryConfig | dict[str, Any] | str | Path | None") -> OdometryConfig:
    """An :class:`OdometryConfig` from itself, a (partial) tree of plain data, a YAML/JSON file's
    path, or None (the defaults): what :func:`gtvo.run`'s ``config`` takes."""
    if value is None:
        return OdometryConfig()
    if isinstance(value, OdometryConfig):
        return value
    if isinstance(value, dict):
        return config_from_dict(value)
    if isinstance(value, (str, Path)):
        return load_config(value)
    raise InputError(f"config must be an OdometryConfig, a dict or a file path, got {type(value).__name__}")


# -- files -----------------------------------------------------------------------------------------
def config_to_yaml(config: OdometryConfig, header: str | None = None) -> str:
    """The whole tree as YAML text (``header``: a comment line on top); :func:`load_config` reads it back."""
    import yaml  # noqa: PLC0415

    text = yaml.safe_dump(config_to_dict(config), sort_keys=False, default_flow_style=None, width=100)
    return (f"# {header}\n" if header else "") + text


def load_config(path: str | Path, base: OdometryConfig | None = None) -> OdometryConfig:
    """The :class:`OdometryConfig` of a YAML (or JSON) file: a partial tree, missing keys keep
    their values in ``base`` (default: the defaults; docs/configuration.md).

    Raises:
        InputError: one line naming the file (and the key): unreadable file, malformed YAML,
            unknown key, wrong type, value out of range.
    """
    import yaml  # noqa: PLC0415

    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the config file: {getattr(exc, 'strerror', None) or exc}", path=p) from None
    try:
        data = yaml.load(text, Loader=_yaml_loader())  # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or "malformed"
        raise InputError(f"not valid YAML: {problem}", path=p, line=None if mark is None else mark.line + 1) from None
    return config_from_dict(data, source=p, base=base)


def _yaml_loader() -> type:
    """PyYAML's ``SafeLoader`` reading ``1e-05`` (JSON's and Python's spelling) as a float, as
    YAML 1.2 does (YAML 1.1 wants ``1.0e-05``)."""
    import yaml  # noqa: PLC0415

    class Loader(yaml.SafeLoader):
        pass

    number = re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$")
    Loader.add_implicit_resolver("tag:yaml.org,2002:float", number, list("-+0123456789"))
    return Loader


# -- documentation ---------------------------------------------------------------------------------
def field_docs(cls: type) -> dict[str, str]:
    """Each field's text from the ``Attributes:`` section of ``cls``'s docstring (one line each;
    an entry ``a, b: text`` documents both)."""
    doc = inspect.getdoc(cls) or ""
    out: dict[str, str] = {}
    section = doc.split("Attributes:", 1)[1] if "Attributes:" in doc else ""
    current: list[str] = []
    for line in section.splitlines():
        m = re.match(r"^    (\w+(?:, \w+)*): (.*)$", line)
        if m:
            current = [n.strip() for n in m.group(1).split(",")]
            for n in current:
                out[n] = m.group(2).strip()
        elif line.startswith("        ") and current:
            for n in current:
                out[n] += " " + line.strip()
        elif line.strip():
            current = []
    return {k: _plain_text(v) for k, v in out.items()}


def _plain_text(text: str) -> str:
    """reST roles and literals as plain text (``:func:`x``` -> ``x``)."""
    text = re.sub(r":\w+:`~?([^`]+)`", r"\1", text)
    return text.replace("``", "")


def describe_key(key: str, config: OdometryConfig | None = None) -> tuple[str, Any, Any]:
    """``(help text, default, hint)`` of a dotted key of the tree (``"frontend.points_per_keyframe"``),
    the default taken from ``config`` (default: :class:`OdometryConfig`'s)."""
    obj: Any = config or OdometryConfig()
    cls: type = OdometryConfig
    *parents, last = key.split(".")
    for name in parents:
        obj = getattr(obj, name)
        cls = _dataclass_of(type_hints(cls)[name])  # type: ignore[assignment]
    return field_docs(cls).get(last, ""), getattr(obj, last), type_hints(cls)[last]


def config_reference() -> str:
    """Every key of the tree with its type, default, range and text, as markdown (docs/configuration.md)."""
    lines = ["| key | type | default | range | meaning |", "|---|---|---|---|---|"]
    _reference_rows(OdometryConfig, OdometryConfig(), "", lines)
    return "\n".join(lines) + "\n"


def _reference_rows(cls: type, obj: Any, path: str, lines: list[str]) -> None:
    docs, hints = field_docs(cls), type_hints(cls)
    for f in dataclasses.fields(cls):
        key = _join(path, f.name)
        if key in _DERIVED:
            continue
        value = getattr(obj, f.name)
        sub = _dataclass_of(hints[f.name])
        kind = _type_name(hints[f.name])
        default = "(below)" if sub is not None and value is not None else f"`{_yaml_scalar(_to_plain(value, key))}`"
        rng = f.metadata.get("range", "")
        lines.append(f"| `{key}` | {kind} | {default} | {rng} | {docs.get(f.name, '').replace('|', chr(92) + '|')} |")
        if sub is not None:
            _reference_rows(sub, value if value is not None else sub(), key, lines)


def _yaml_scalar(value: Any) -> str:
    """A plain value as a config file spells it (``true``, ``null``, ``[1.0, 2.0]``)."""
    import json  # noqa: PLC0415

    return value if isinstance(value, str) else json.dumps(value)


def _type_name(hint: Any) -> str:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Literal:
        return " / ".join(f"`{a}`" for a in args)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in args)
    if origin is tuple:
        return "list" if len(args) == 2 and args[1] is Ellipsis else f"{len(args)} numbers"
    if hint is type(None):
        return "null"
    return "section" if dataclasses.is_dataclass(hint) else getattr(hint, "__name__", str(hint))
