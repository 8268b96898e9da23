"""Settings a log folder carries beside its images: ``wheel.yaml``, read like its calibration.

A log with wheel odometry may carry the ``wheel:`` section of the configuration tree that reads it
(the calibration model, ``base_to_camera``, the nominal track width; ``gtvo synthetic --wheel``
writes one). ``gtvo run`` and ``gtvo batch`` read it without ``--config``, as they read the
log's ``calib.txt``, and say so on the console. What the user chose explicitly wins: a key of
the ``wheel:`` section that the run's settings (``--config``, a batch's per-log overrides) set
to something other than its default keeps that value; the log's file fills the rest.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gtvo.errors import InputError

#: The file name of a log's wheel settings, beside its images.
LOG_WHEEL_SETTINGS = "wheel.yaml"


def log_wheel_settings(log: str | Path, config: Any) -> tuple[Any, Path | None]:
    """``config`` (an :class:`gtvo.config.OdometryConfig`) with the log folder's ``wheel.yaml``
    under it (module doc), and the file read (None: the log has none, or is no folder).

    Raises:
        InputError: one line naming the file (and the key): unreadable, malformed, a key that is
            not the ``wheel:`` section's, a bad value.
    """
    from gtvo.config import OdometryConfig, config_from_dict, config_to_dict, load_config  # noqa: PLC0415

    path = Path(log) / LOG_WHEEL_SETTINGS
    if not Path(log).is_dir() or not path.is_file():
        return config, None
    _check_only_wheel(path)
    from_log = config_to_dict(load_config(path))["wheel"]
    defaults = config_to_dict(OdometryConfig())["wheel"]
    chosen = {k: v for k, v in config_to_dict(config)["wheel"].items() if v != defaults.get(k)}
    return config_from_dict({"wheel": {**from_log, **chosen}}, base=config), path


def _check_only_wheel(path: Path) -> None:
    import yaml  # noqa: PLC0415

    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return  # load_config says what is wrong, naming the file and the line
    if isinstance(data, dict):
        other = sorted(str(k) for k in data if k != "wheel")
        if other:
            raise InputError(f"a log's {LOG_WHEEL_SETTINGS} holds only the wheel: section of the settings, got "
                             f"{other[0]!r} (give other settings with --config)", path=path)


def wheel_settings_line(path: Path) -> str:
    """The console's line for a log's wheel settings that were read."""
    return (f"wheel settings from the log's {path} (the wheel: keys --config sets to other than their "
            f"defaults win)")
