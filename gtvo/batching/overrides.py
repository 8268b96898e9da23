"""Per-log configuration overrides of ``gtvo batch``: a nested mapping applied to the dataclass
tree of :class:`gtvo.config.OdometryConfig`, and the configuration's identity (a short hash).

Stand-in until the nested configuration module (``gtvo/config.py``, issue 19) loads
configurations itself: :func:`apply_overrides` is the one place to swap for its loader.

>>> cfg = apply_overrides(OdometryConfig(), {"points_per_keyframe": 400, "window": {"size": 5}},
...                       where="fleet.yaml, log 2")          # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import types
import typing
from typing import Any, Literal

from gtvo.errors import InputError

#: Length of the configuration identity (hex digits of sha256 of the canonical JSON).
CONFIG_ID_LENGTH = 12


def apply_overrides(config: Any, overrides: dict[str, Any] | None, where: str = "") -> Any:
    """A copy of the frozen dataclass ``config`` with the nested ``overrides`` applied.

    A key names a field; a mapping value for a dataclass field is applied to that field's
    current value (or its type's defaults when the field is None). Values are checked against
    the field's type (numbers, bools, the allowed strings of a ``Literal``, fixed-length lists
    for tuples, nested lists for arrays, None where allowed) and the dataclass's own checks run.

    Raises:
        InputError: an unknown key, a value of the wrong type, or a value the configuration
            refuses; the message names the dotted key and ``where`` (e.g. the SPEC file).
    """
    if not overrides:
        return config
    if not isinstance(overrides, dict):
        raise InputError(f"{_at(where)}config must be a mapping of settings, got {_kind(overrides)}")
    return _apply(config, overrides, "", where)


def _apply(obj: Any, overrides: dict[str, Any], prefix: str, where: str) -> Any:
    hints = typing.get_type_hints(type(obj))
    names = {f.name for f in dataclasses.fields(obj)}
    changes: dict[str, Any] = {}
    for key, value in overrides.items():
        dotted = f"{prefix}{key}"
        if key not in names:
            known = ", ".join(sorted(names))
            raise InputError(f"{_at(where)}unknown configuration key {dotted!r} (known here: {known})")
        changes[key] = _convert(getattr(obj, key), hints[key], value, dotted, where)
    try:
        return dataclasses.replace(obj, **changes)
    except InputError as exc:
        raise InputError(f"{_at(where)}configuration {prefix.rstrip('.') or 'top level'}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise InputError(f"{_at(where)}configuration {prefix.rstrip('.') or 'top level'}: {exc}") from None


def _convert(current: Any, hint: Any, value: Any, key: str, where: str) -> Any:
    """``value`` checked (and converted) for a field of type ``hint`` whose value is ``current``."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        options = [a for a in args if a is not type(None)]
        if value is None and len(options) < len(args):
            return None
        if len(options) == 1:
            return _convert(current, options[0], value, key, where)
        raise InputError(f"{_at(where)}configuration key {key!r} cannot be overridden (type {hint})")
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, dict):
            raise InputError(f"{_at(where)}configuration key {key!r} must be a mapping, got {_kind(value)}")
        return _apply(current if current is not None else hint(), value, f"{key}.", where)
    if origin is Literal:
        if value not in args:
            choices = ", ".join(repr(a) for a in args)
            raise InputError(f"{_at(where)}configuration key {key!r} must be one of {choices}, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise InputError(f"{_at(where)}configuration key {key!r} must be true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(f"{_at(where)}configuration key {key!r} must be an integer, got {value!r}")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"{_at(where)}configuration key {key!r} must be a number, got {value!r}")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise InputError(f"{_at(where)}configuration key {key!r} must be a string, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)) or (args and args[-1] is not Ellipsis and len(value) != len(args)):
            n = "" if not args or args[-1] is Ellipsis else f"{len(args)} "
            raise InputError(f"{_at(where)}configuration key {key!r} must be a list of {n}values, got {value!r}")
        items = args[:1] * len(value) if args and args[-1] is Ellipsis else args
        return tuple(_convert(None, a, v, f"{key}[{i}]", where) for i, (a, v) in enumerate(zip(items, value)))
    if _is_array(hint):
        return _array(current, value, key, where)
    raise InputError(f"{_at(where)}configuration key {key!r} cannot be overridden (type {hint})")


def _is_array(hint: Any) -> bool:
    origin = typing.get_origin(hint) or hint
    return getattr(origin, "__name__", "") == "ndarray" and getattr(origin, "__module__", "") == "numpy"


def _array(current: Any, value: Any, key: str, where: str) -> Any:
    import numpy as np  # noqa: PLC0415 - gtvo.batching stays numpy-free until a worker's BLAS is set

    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{_at(where)}configuration key {key!r} must be a list of numbers, got {value!r}") from None
    if current is not None and arr.ndim != np.ndim(current) or not np.all(np.isfinite(arr)) or arr.size == 0:
        shape = "x".join(str(s) for s in np.shape(current)) if current is not None else "?"
        raise InputError(f"{_at(where)}configuration key {key!r} must be finite numbers shaped like {shape}, "
                         f"got {value!r}")
    if current is not None and np.ndim(current) == 2 and arr.shape[1] != np.shape(current)[1]:
        raise InputError(f"{_at(where)}configuration key {key!r} must have {np.shape(current)[1]} columns, "
                         f"got {value!r}")
    return arr


def canonical(config: Any) -> Any:
    """The configuration as plain JSON values (dataclasses as mappings, arrays and tuples as lists)."""
    if dataclasses.is_dataclass(config) and not isinstance(config, type):
        return {f.name: canonical(getattr(config, f.name)) for f in dataclasses.fields(config)}
    if isinstance(config, (list, tuple)):
        return [canonical(v) for v in config]
    if hasattr(config, "tolist"):  # numpy arrays and scalars
        return canonical(config.tolist())
    if isinstance(config, dict):
        return {str(k): canonical(v) for k, v in config.items()}
    return config


def config_identity(config: Any) -> str:
    """A short identity of a resolved configuration: the first :data:`CONFIG_ID_LENGTH` hex digits
    of the sha256 of its canonical JSON (sorted keys, no spaces). Equal settings, equal identity."""
    text = json.dumps(canonical(config), sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:CONFIG_ID_LENGTH]


def _at(where: str) -> str:
    return f"{where}: " if where else ""


def _kind(value: Any) -> str:
    return f"{type(value).__name__} {value!r}"
