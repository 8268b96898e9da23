"""Argument helpers shared by subcommands."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from gtvo.errors import InputError

if TYPE_CHECKING:
    from gtvo.report import RunReport


def parse_floats(text: str, n: int, what: str) -> tuple[float, ...]:
    """Parse ``"a,b,c"`` into ``n`` finite floats, or raise :class:`InputError` naming ``what``."""
    parts = [p.strip() for p in text.split(",")]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        raise InputError(f"{what} must be {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n or not all(v == v and abs(v) != float("inf") for v in vals):
        raise InputError(f"{what} must be {n} comma-separated finite numbers, got {text!r}")
    return vals


#: The odometry's flags and the key of the configuration tree each sets (``--solver`` sets both
#: ``solver.tracker`` and ``solver.window``). Their defaults and help texts are the tree's.
ODOMETRY_FLAGS: tuple[tuple[str, str, str | None], ...] = (
    ("--mode", "mode", None),
    ("--window-backend", "window.backend", None),
    ("--points", "frontend.points_per_keyframe", "N"),
    ("--motion-model", "motion_model.model", None),
)


def add_odometry_options(p: argparse.ArgumentParser, defaults: Any = None) -> None:
    """Options of the odometry shared by ``run`` and ``demo``: ``--config FILE`` and the flags of
    :data:`ODOMETRY_FLAGS`, each defaulting to the value in ``defaults`` (an ``OdometryConfig``;
    default the library's), which :func:`odometry_config` starts from."""
    from gtvo.config import OdometryConfig, describe_key  # noqa: PLC0415
    from gtvo.core.settings import literal_choices  # noqa: PLC0415

    base = defaults if defaults is not None else OdometryConfig()
    p.add_argument("--config", metavar="FILE.yaml", default=None,
                   help="settings from a YAML (or JSON) file: any key of the configuration tree "
                        "(docs/configuration.md), e.g. the config.yaml of an earlier run; flags override it")
    for flag, key, metavar in ODOMETRY_FLAGS:
        text, default, hint = describe_key(key, base)
        choices = literal_choices(hint)
        kind = {"type": _cli_choice} if choices else {"type": hint, "metavar": metavar}
        for choice in choices or ():  # the help names the values as they are typed here
            text = text.replace(f'"{choice}"', f'"{_cli(choice)}"')
        alike = "; '-' or '_' alike" if any("_" in c or "-" in c for c in choices or ()) else ""
        p.add_argument(flag, default=None, choices=None if choices is None else [_cli(c) for c in choices],
                       help=_help(f"{text.rstrip('.')} (config key {key}; default: {_cli(default)}{alike})"), **kind)
    p.add_argument("--solver", choices=[_cli(c) for c in literal_choices(describe_key("solver.tracker")[2]) or ()],
                   default=None,
                   help=f"the solver of both the tracker and the window (config keys solver.tracker and "
                        f"solver.window; default: {base.solver.tracker} tracker, {base.solver.window} window)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(odometry_defaults=base)


def _cli(value: Any) -> Any:
    """A setting's spelling on the command line (``fixed_lag`` -> ``fixed-lag``)."""
    return value.replace("_", "-") if isinstance(value, str) else value


def _cli_choice(text: str) -> str:
    """A choice as typed, in the command line's spelling: ``fixed_lag`` and ``fixed-lag`` alike
    (the configuration file's spelling and the flag's)."""
    return _cli(text)


def _help(text: str) -> str:
    return text.replace("%", "%%")  # argparse formats help texts with %


def odometry_config(args: Any):
    """The run's :class:`OdometryConfig`: the defaults (``args.odometry_defaults``), then the
    ``--config`` file, then the flags that were given (a bad value: one line naming the flag)."""
    from gtvo.config import ConfigKeyError, config_from_dict, load_config  # noqa: PLC0415

    config = args.odometry_defaults
    if args.config is not None:
        config = load_config(args.config, base=config)
    flags = [*ODOMETRY_FLAGS, ("--solver", "solver", None)]
    for flag, key, _ in flags:
        value = getattr(args, flag[2:].replace("-", "_"))
        if value is None:
            continue
        tree: Any = _config_spelling(key, value)
        if key == "solver":  # one solver for the tracker and the window
            tree = {"tracker": value, "window": value}
        for name in reversed(key.split(".")):
            tree = {name: tree}
        try:
            config = config_from_dict(tree, base=config)
        except ConfigKeyError as exc:
            raise InputError(f"{flag} {exc.detail}") from None
    if args.window_backend is not None and config.mode != "window":
        raise InputError(f"--window-backend {args.window_backend} needs --mode window (got --mode {config.mode})")
    return config


def _config_spelling(key: str, value: Any) -> Any:
    """The configuration's value of a flag's choice (``fixed-lag`` -> ``fixed_lag`` for
    ``window.backend``; ``constant-velocity`` stays); other values as they are."""
    from gtvo.config import describe_key  # noqa: PLC0415
    from gtvo.core.settings import literal_choices  # noqa: PLC0415

    if key == "solver" or not isinstance(value, str):
        return value
    choices = literal_choices(describe_key(key)[2]) or ()
    return {_cli(c): c for c in choices}.get(_cli(value), value)


def describe_solvers(report: RunReport) -> str:
    """What ran, from a run's report: mode, the tracker's solver and the window's back end and solver."""
    text = f"{report['mode']}, tracker {report['tracker_solver']}"
    if report.get("window_backend") is not None:
        text += f", window {_cli(report['window_backend'])} back end with {report['window_solver']}"
    if report.get("loop_closure_solver") is not None:
        text += f", loop closure {report['loop_closure_solver']}"
    return text


def print_report(report: RunReport) -> None:
    """Print the headline figures of a run's report (:func:`gtvo.report.headline`), one per line,
    values in one column."""
    from gtvo.report import headline  # noqa: PLC0415

    shown = headline(report)
    width = max((len(k) for k, _ in shown), default=0) + 1
    for k, v in shown:
        print(f"  {k:<{width}} {v:.4g}" if isinstance(v, float) else f"  {k:<{width}} {v}")
    for line in flagged_frame_lines(report.get("frame_outcomes") or {}):
        print(f"  {line}")
    if report.get("wheel_calibration") is not None:
        from gtvo.odometry.wheel import wheel_calibration_line  # noqa: PLC0415

        print(f"  {wheel_calibration_line(report['wheel_calibration'])}")
    if report.get("imu") is not None:
        from gtvo.odometry.imu import imu_line  # noqa: PLC0415

        print(f"  {imu_line(report['imu'])}")
    print(f"  outputs in {report['out']}")


def flagged_frame_lines(outcomes: dict[str, Any]) -> list[str]:
    """One line per kind of flagged frame, naming them and their reasons (short forms), e.g.
    ``suspect frames: 25, 30, 31 (no image motion while the rig moved / motion reversed ...)``."""
    lines = []
    for name in ("frozen", "suspect", "lost", "reinitialised", "wheel_carried", "imu_carried", "recovered", "skipped"):
        frames = outcomes.get(name)
        if not isinstance(frames, list) or not frames:
            continue
        reasons = list(dict.fromkeys(str(f.get("reason", "")).split(" (")[0] for f in frames))
        indices = ", ".join(str(f["index"]) for f in frames)
        why = " / ".join(r for r in reasons if r)
        lines.append(f"{name} frames: {indices}" + (f" ({why})" if why else ""))
    return lines
