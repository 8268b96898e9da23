"""Checked settings for gtvo's frozen config dataclasses: a field's allowed range and its check.

A config field declares its range once, beside its default::

    size: int = setting(7, ">= 2")
    min_visible: float = setting(0.7, "[0, 1]")

and the dataclass calls :func:`check_settings` in ``__post_init__``: a value outside its range,
or a ``Literal`` field given a value it does not list, raises :class:`SettingError`, an
:class:`gtvo.errors.InputError` that names the field (``key``), so a config file's loader can
name ``window.size`` and the file (:mod:`gtvo.config`). Ranges are an interval ``[a, b]``,
``(a, b]``, ``[a, b)``, ``(a, b)``, or ``> x``, ``>= x``, ``< x``, ``<= x``. A value must be a
finite number inside it: infinity passes only where the range names it as a closed end
(``(0, inf]``: "inf switches the check off"), NaN never. A tuple is checked element by element;
None always passes (an optional setting switched off).
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import types
import typing
from typing import Any, Literal

from gtvo.errors import InputError, show

_MISSING: Any = dataclasses.MISSING


class SettingError(InputError):
    """A setting with a bad value; ``key`` is the field's name (a dotted path once a loader
    prefixes the parents)."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key = key
        self.detail = message


def setting(default: Any = _MISSING, range: str | None = None, *, factory: Any = _MISSING) -> Any:
    """A dataclass field with a default (or ``factory``) and an allowed ``range`` (module doc)."""
    if range is not None:
        parse_range(range)  # a typo fails at import time, not at the first bad value
    meta = {} if range is None else {"range": range}
    if factory is not _MISSING:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


@functools.lru_cache(maxsize=None)
def parse_range(text: str) -> tuple[float, float, bool, bool]:
    """``(lo, hi, lo_closed, hi_closed)`` of a range string (module doc)."""
    t = text.strip()
    for op, closed in ((">=", True), ("<=", True), (">", False), ("<", False)):
        if t.startswith(op):
            x = float(t[len(op):])  # the other end open: infinity is not in the range
            return (x, math.inf, closed, False) if op[0] == ">" else (-math.inf, x, False, closed)
    if len(t) >= 5 and t[0] in "[(" and t[-1] in "])" and "," in t:
        a, b = (float(s) for s in t[1:-1].split(","))
        return a, b, t[0] == "[", t[-1] == "]"
    raise ValueError(f"bad setting range {text!r}")


def in_range(value: float, text: str) -> bool:
    """Whether ``value`` lies in the range ``text``."""
    lo, hi, lo_closed, hi_closed = parse_range(text)
    above = value >= lo if lo_closed else value > lo
    below = value <= hi if hi_closed else value < hi
    return bool(above and below)


@functools.lru_cache(maxsize=None)
def type_hints(cls: type) -> dict[str, Any]:
    """The resolved annotations of a dataclass (cached)."""
    return typing.get_type_hints(cls)


def literal_choices(hint: Any) -> tuple[Any, ...] | None:
    """The values a ``Literal`` (or ``Literal | None``) hint allows; None for any other hint."""
    if typing.get_origin(hint) is Literal:
        return typing.get_args(hint)
    args = typing.get_args(hint)
    if args and type(None) in args:
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1 and typing.get_origin(inner[0]) is Literal:
            return typing.get_args(inner[0]) + (None,)
    return None


def check_settings(obj: Any) -> None:
    """Check every field of the dataclass ``obj`` against its ``Literal`` choices and ``range``.

    Raises:
        SettingError: naming the first bad field.
    """
    hints = type_hints(type(obj))
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        choices = literal_choices(hints.get(f.name))
        if choices is not None and value not in choices:
            allowed = ", ".join(repr(c) for c in choices)
            raise SettingError(f.name, f"must be one of {allowed}, got {show(value)}")
        rng = f.metadata.get("range")
        if rng is None or value is None:
            continue
        values = value if isinstance(value, tuple) else (value,)
        for v in values:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not in_range(float(v), rng):
                raise SettingError(f.name, f"must be {_describe(rng)}, got {show(value)}")


def _describe(rng: str) -> str:
    t = rng.strip()
    return f"in {t}" if t[0] in "[(" else t


def check_nested(obj: Any) -> None:
    """:func:`check_settings` plus: every nested-config field holds its config class (or None
    where allowed), so a wrong object fails here, naming the field, not deep in a run."""
    check_settings(obj)
    hints = type_hints(type(obj))
    for f in dataclasses.fields(obj):
        cls, value = dataclass_of(hints[f.name]), getattr(obj, f.name)
        if cls is not None and not isinstance(value, cls) and not (value is None and _optional(hints[f.name])):
            raise SettingError(f.name, f"must be a {cls.__name__}, got {value!r}")


def _optional(hint: Any) -> bool:
    return type(None) in typing.get_args(hint) and typing.get_origin(hint) in (typing.Union, types.UnionType)


def dataclass_of(hint: Any) -> type | None:
    """The dataclass of a ``Config`` or ``Config | None`` hint, else None."""
    for h in (hint, *typing.get_args(hint)):
        if inspect.isclass(h) and dataclasses.is_dataclass(h):
            return h
    return None
