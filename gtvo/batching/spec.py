"""The SPEC of ``gtvo batch``: which logs to run, under which names, with which settings.

A SPEC is either

* a folder: every entry that :func:`gtvo.datasets.detect_format` recognises is a log (so every
  layout the readers learn is picked up); a sub-folder it does not recognise is kept as a log
  that fails with the reason (a broken log is reported, never silently dropped), while plain
  files it does not recognise (notes, a README) and hidden entries are ignored; or
* a YAML file holding a list, one entry per log: a path, or a mapping with ``path`` and the
  optional keys of :data:`ENTRY_KEYS` (``config`` is a nested mapping of
  :class:`gtvo.config.OdometryConfig` settings; relative paths are relative to the YAML file).

Every problem with the SPEC itself is an :class:`InputError` naming the file and the entry.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gtvo.core.paths import identity, link_problem, resolved
from gtvo.errors import InputError

#: Keys a YAML entry may have (besides ``path``).
ENTRY_KEYS: tuple[str, ...] = ("name", "format", "config", "max_frames", "frame_step", "loop_closure", "camera",
                               "ground_truth", *("left_topic", "right_topic", "depth_topic", "ground_truth_topic",
                                                 "stamp_tolerance", "calib"))

#: Keys of a ROS bag's reading (as ``gtvo run``'s flags of the same names): topics, then the rest.
BAG_TOPIC_KEYS: tuple[str, ...] = ("left_topic", "right_topic", "depth_topic", "ground_truth_topic")

#: Names a log's output folder may not take: the batch's own files.
RESERVED_NAMES: frozenset[str] = frozenset({"summary.json", "summary.md", "summary.png"})


@dataclass(frozen=True)
class LogSpec:
    """One log of a batch: what ``gtvo run`` gets for it.

    Attributes:
        name: the output folder name inside the batch's ``--out``.
        path: the log (absolute).
        format: the dataset layout, ``"auto"`` to detect it.
        config: the configuration overrides of this log (nested mapping, applied to the batch's
            base configuration), empty for none.
        options: further ``gtvo.run`` options set for this log (``max_frames``, ``frame_step``,
            ``loop_closure``, ``camera``, ``ground_truth``; for ROS bags ``calib``, the topics of
            :data:`BAG_TOPIC_KEYS` and ``stamp_tolerance``).
        problem: why the SPEC folder's entry is not a recognised log (the log then fails).
    """

    name: str
    path: Path
    format: str = "auto"
    config: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)
    problem: str | None = None


def read_spec(spec: str | Path | list[Any], exclude: tuple[Path, ...] = ()) -> list[LogSpec]:
    """The logs of ``spec`` (a folder, a YAML file, or the YAML's list itself), in order.

    ``exclude``: folders not to take for logs (the batch's output folder when it sits inside; by file
    identity); one that is a recognised log is refused (:class:`InputError`: outputs would go into it).

    Raises:
        InputError: a missing SPEC, unreadable YAML, a bad entry, two logs of one name, no logs.
    """
    if isinstance(spec, list):
        logs = _from_list(spec, Path.cwd(), "SPEC list")
    else:
        path = Path(spec)
        if not path.exists():
            broken = link_problem(path)
            raise InputError(f"SPEC is {broken}" if broken else "SPEC not found", path=path)
        logs = _from_folder(path, exclude) if path.is_dir() else _from_yaml(path)
    if not logs:
        raise InputError("SPEC holds no logs", path=None if isinstance(spec, list) else spec)
    _check_unique([lg.name for lg in logs], "SPEC list" if isinstance(spec, list) else str(spec))
    return logs


def _from_folder(folder: Path, exclude: tuple[Path, ...]) -> list[LogSpec]:
    from gtvo.datasets import detect_format  # noqa: PLC0415

    try:
        kind = detect_format(folder)
    except InputError:
        kind = None
    if kind is not None:
        raise InputError(f"SPEC is itself one log ({kind} layout): give the folder that holds it, or run it "
                         f"with gtvo run", path=folder)
    skip = {identity(p) for p in exclude} - {None}
    logs = []
    for entry in sorted(folder.iterdir(), key=lambda p: p.name):
        if entry.name.startswith("."):
            continue
        broken = link_problem(entry)
        if broken is not None:  # reported as a failed log: a link that cannot be followed is no note
            logs.append(LogSpec(name=_check_name(entry.name, str(entry)), path=Path(os.path.abspath(entry)),
                                problem=f"{entry} is {broken}"))
            continue
        try:
            kind = detect_format(entry)
            problem = None
        except InputError as exc:
            if identity(entry) in skip:
                continue  # the batch's own output folder inside the SPEC folder
            if not entry.is_dir():
                continue  # a note or a file of another kind beside the logs
            kind, problem = "auto", f"not a log: {exc}"
        if identity(entry) in skip:
            raise InputError(f"the output folder is the log {entry}: its outputs would be written into the log's "
                             f"data; choose another --out", path=entry)
        name = entry.name if entry.is_dir() else entry.stem
        logs.append(LogSpec(name=_check_name(name, str(entry)), path=entry.resolve(), format=kind, problem=problem))
    return logs


def _from_yaml(path: Path) -> list[LogSpec]:
    import yaml  # noqa: PLC0415

    from gtvo.datasets import detect_format  # noqa: PLC0415

    try:
        kind = detect_format(path)
    except InputError:
        kind = None
    if kind is not None:  # a bag file
        raise InputError(f"SPEC is itself one log ({kind}): give the folder that holds it, or run it with gtvo run",
                         path=path)

    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise InputError("SPEC is neither a folder nor a YAML text file", path=path) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise InputError(f"not valid YAML ({getattr(exc, 'problem', None) or exc})", path=path,
                         line=None if mark is None else mark.line + 1) from None
    if not isinstance(data, list):
        raise InputError(f"SPEC YAML must be a list of logs, got {type(data).__name__}", path=path)
    return _from_list(data, path.resolve().parent, str(path))


def _from_list(items: list[Any], base: Path, where: str) -> list[LogSpec]:
    return [_entry(item, i + 1, base, where) for i, item in enumerate(items)]


def _entry(item: Any, number: int, base: Path, where: str) -> LogSpec:
    at = f"{where}, log {number}"
    if isinstance(item, str):
        item = {"path": item}
    if not isinstance(item, dict):
        raise InputError(f"{at}: an entry is a path or a mapping with 'path', got {item!r}")
    if "path" not in item or not isinstance(item["path"], str) or not item["path"]:
        raise InputError(f"{at}: 'path' (the log) is required and must be a string")
    unknown = sorted(set(item) - {"path", *ENTRY_KEYS})
    if unknown:
        raise InputError(f"{at}: unknown key {unknown[0]!r} (known: path, {', '.join(ENTRY_KEYS)})")
    broken = link_problem((base / Path(item["path"]).expanduser()))
    log = _resolve(base, item["path"]) if broken is None else Path(os.path.abspath(base / item["path"]))
    default_name = log.name if log.is_dir() or not log.suffix else log.stem
    name = item.get("name", default_name)
    if not isinstance(name, str):
        raise InputError(f"{at}: 'name' must be a string, got {name!r}")
    fmt = item.get("format", "auto")
    _check_format(fmt, at)
    config = item.get("config") or {}
    if not isinstance(config, dict):
        raise InputError(f"{at}: 'config' must be a mapping of settings, got {config!r}")
    options = _options(item, base, at)
    return LogSpec(name=_check_name(name, at), path=log, format=fmt, config=config, options=options,
                   problem=None if broken is None else f"{log} is {broken}")


def _check_format(fmt: Any, at: str) -> None:
    from gtvo.datasets import FORMATS  # noqa: PLC0415 - the readers' own list: new layouts come with them

    if fmt != "auto" and fmt not in FORMATS:
        raise InputError(f"{at}: unknown 'format' {fmt!r} (known: auto, {', '.join(FORMATS)})")


def _options(item: dict[str, Any], base: Path, at: str) -> dict[str, Any]:
    options: dict[str, Any] = {}
    for key in ("max_frames", "frame_step"):
        if key in item:
            v = item[key]
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InputError(f"{at}: {key!r} must be an integer >= 1, got {v!r}")
            options[key] = v
    if "loop_closure" in item:
        if not isinstance(item["loop_closure"], bool):
            raise InputError(f"{at}: 'loop_closure' must be true or false, got {item['loop_closure']!r}")
        options["loop_closure"] = item["loop_closure"]
    if "camera" in item:
        cam = item["camera"]
        if (not isinstance(cam, list) or len(cam) != 4
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in cam)):
            raise InputError(f"{at}: 'camera' must be a list [fx, fy, cx, cy], got {cam!r}")
        options["camera"] = tuple(float(v) for v in cam)
    for key in ("ground_truth", "calib"):
        if key in item:
            value = item[key]
            if not isinstance(value, str) or not value:
                raise InputError(f"{at}: {key!r} must be a file path, got {value!r}")
            options[key] = str(_resolve(base, value))
    for key in BAG_TOPIC_KEYS:
        if key in item:
            if not isinstance(item[key], str) or not item[key]:
                raise InputError(f"{at}: {key!r} must be a topic name, got {item[key]!r}")
            options[key] = item[key]
    if "stamp_tolerance" in item:
        tol = item["stamp_tolerance"]
        if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not tol > 0:
            raise InputError(f"{at}: 'stamp_tolerance' must be a positive number of seconds, got {tol!r}")
        options["stamp_tolerance"] = float(tol)
    return options


def _resolve(base: Path, text: str) -> Path:
    """``text`` against ``base``, links followed; one that cannot be followed (a loop) is kept as
    written, made absolute: its log then fails with the reason, the others run."""
    p = Path(text).expanduser()
    p = p if p.is_absolute() else base / p
    try:
        return resolved(p)
    except InputError:
        return Path(os.path.abspath(p))


def _check_name(name: str, at: str) -> str:
    """``name`` if it can name one folder inside the batch's output folder."""
    if (not name.strip() or name.startswith((".", "-")) or any(c in name for c in '/\\\0')
            or not name.isprintable() or name in RESERVED_NAMES):
        raise InputError(f"{at}: log name {name!r} cannot be a folder name of the batch (one folder name, "
                         f"not starting with '.' or '-', not {', '.join(sorted(RESERVED_NAMES))})")
    return name


def _check_unique(names: list[str], where: str) -> None:
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise InputError(f"{where}: two logs are named {name!r}; give each a distinct 'name'")
        seen.add(name)
