"""Per-log configuration overrides of ``gtvo batch`` and the configuration's identity.

A log's ``config`` (a nested mapping) is applied to the batch's base configuration by the
configuration module's own loader (:func:`gtvo.config.files.config_from_dict`), so a batch SPEC
takes exactly the keys a configuration file takes (docs/configuration.md).
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

from gtvo.errors import InputError

#: Length of the configuration identity (hex digits of sha256 of the canonical JSON).
CONFIG_ID_LENGTH = 12


def apply_overrides(config: Any, overrides: dict[str, Any] | None, where: str = "") -> Any:
    """``config`` (an :class:`gtvo.config.OdometryConfig`) with the nested ``overrides`` applied.

    Raises:
        InputError: an unknown key, a value of the wrong type or out of its range; the one line
            names ``where`` (the SPEC file and the log) and the dotted key.
    """
    from gtvo.config.files import config_from_dict  # noqa: PLC0415

    if not overrides:
        return config
    if not isinstance(overrides, dict):
        raise InputError(f"{where + ': ' if where else ''}config must be a mapping of settings, "
                         f"got {type(overrides).__name__} {overrides!r}")
    return config_from_dict(overrides, source=where or None, base=config)


def canonical(config: Any) -> Any:
    """The configuration as plain JSON values (dataclasses as mappings, arrays and tuples as lists)."""
    import dataclasses  # noqa: PLC0415

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
