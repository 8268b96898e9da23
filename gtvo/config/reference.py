"""The tree's own documentation: each field's text from its class docstring (:func:`field_docs`),
a key's help, default and type for the CLI (:func:`describe_key`), and the table of every key in
docs/configuration.md (:func:`config_reference`)."""

from __future__ import annotations

import dataclasses
import inspect
import json
import re
import types
import typing
from typing import Any, Literal

from gtvo.config.files import _join, _to_plain
from gtvo.config.tree import OdometryConfig
from gtvo.core.settings import dataclass_of, type_hints

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
        cls = dataclass_of(type_hints(cls)[name])  # type: ignore[assignment]
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
        value = getattr(obj, f.name)
        sub = dataclass_of(hints[f.name])
        kind = _type_name(hints[f.name])
        default = "(below)" if sub is not None and value is not None else f"`{_yaml_scalar(_to_plain(value, key))}`"
        rng = f.metadata.get("range", "")
        lines.append(f"| `{key}` | {kind} | {default} | {rng} | {docs.get(f.name, '').replace('|', chr(92) + '|')} |")
        if sub is not None:
            _reference_rows(sub, value if value is not None else sub(), key, lines)


def _yaml_scalar(value: Any) -> str:
    """A plain value as a config file spells it (``true``, ``null``, ``[1.0, 2.0]``)."""
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
