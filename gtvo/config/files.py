"""A run's configuration as plain data and files: :func:`config_to_dict` and its exact inverse
:func:`config_from_dict` (every key, type and range checked; an error names the key and the
source), :func:`config_to_yaml`, :func:`load_config` (YAML or JSON) and :func:`as_config`."""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import types
import typing
from pathlib import Path
from typing import Any, Literal

import numpy as np

from gtvo.config.tree import OdometryConfig
from gtvo.core.settings import SettingError, type_hints
from gtvo.errors import InputError

#: Keys of earlier versions and the key that holds each setting now: a config file that uses one
#: is told which key to set (they are not read: one name per setting).
MOVED_KEYS: dict[str, str] = {
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
    "tracker_solver": "solver.tracker",
    "loop_closure": "loops.enabled",
    **{f"{section}.{key}": f"photometric.{key}" for section in ("tracking", "window")
       for key in ("sigma_intensity", "huber_k", "pattern")},
    "tracking.clip_range": "photometric.clip_range",
}


def config_to_dict(config: OdometryConfig) -> dict[str, Any]:
    """The whole tree as plain JSON/YAML data (dicts, lists, str, numbers, bools, None); infinite
    floats are the strings ``"inf"`` / ``"-inf"``. :func:`config_from_dict` inverts it exactly."""
    return _to_plain(config, "")


def _to_plain(obj: Any, path: str) -> Any:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _to_plain(getattr(obj, f.name), _join(path, f.name)) for f in dataclasses.fields(obj)}
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
    names = [f.name for f in dataclasses.fields(cls)]
    for key in data:
        if _join(path, str(key)) in MOVED_KEYS:
            raise SettingError(_join(path, str(key)), f"is now key '{MOVED_KEYS[_join(path, str(key))]}'; set that")
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


def config_to_yaml(config: OdometryConfig, header: str | None = None) -> str:
    """The whole tree as YAML text (``header``: a comment line on top); :func:`load_config` reads it back."""
    import yaml  # noqa: PLC0415

    text = yaml.safe_dump(config_to_dict(config), sort_keys=False, default_flow_style=None, width=100)
    return (f"# {header}\n" if header else "") + text


def load_config(path: str | Path, base: OdometryConfig | None = None) -> OdometryConfig:
    """The :class:`OdometryConfig` of a YAML (or JSON) file: a partial tree, missing keys keep
    their values in ``base`` (default: the defaults; docs/configuration.md).

    Raises:
        InputError: one line naming the file (and the key): unreadable file, malformed YAML, a
            key given twice in one mapping (with its line), unknown key, wrong type, value out of range.
    """
    import yaml  # noqa: PLC0415

    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the config file: {getattr(exc, 'strerror', None) or exc}", path=p) from None
    try:
        loader = _yaml_loader()
        _refuse_duplicate_keys(yaml.compose(text, Loader=loader), "", p)  # noqa: S506 (a SafeLoader)
        data = yaml.load(text, Loader=loader)  # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or "malformed"
        raise InputError(f"not valid YAML: {problem}", path=p, line=None if mark is None else mark.line + 1) from None
    return config_from_dict(data, source=p, base=base)


def _refuse_duplicate_keys(node: Any, path: str, source: Path) -> None:
    """An :class:`InputError` naming the file, the dotted key and its line when a mapping of the
    YAML ``node`` gives a key twice (YAML would keep the last one silently)."""
    import yaml  # noqa: PLC0415

    if isinstance(node, yaml.MappingNode):
        seen: set[str] = set()
        for key_node, value_node in node.value:
            key = str(key_node.value)
            if key in seen:
                raise InputError(f"key '{_join(path, key)}' given twice", path=source,
                                 line=key_node.start_mark.line + 1)
            seen.add(key)
            _refuse_duplicate_keys(value_node, _join(path, key), source)
    elif isinstance(node, yaml.SequenceNode):
        for item in node.value:
            _refuse_duplicate_keys(item, path, source)


def _yaml_loader() -> type:
    """PyYAML's ``SafeLoader`` reading ``1e-05`` (JSON's and Python's spelling) as a float, as
    YAML 1.2 does (YAML 1.1 wants ``1.0e-05``)."""
    import yaml  # noqa: PLC0415

    class Loader(yaml.SafeLoader):
        pass

    number = re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$")
    Loader.add_implicit_resolver("tag:yaml.org,2002:float", number, list("-+0123456789"))
    return Loader
