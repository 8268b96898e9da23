"""Dataset readers: KITTI odometry, KITTI raw, EuRoC MAV (ASL) and TUM RGB-D folders and ROS bags as a
lazy :class:`gtvo.datasets.sequence.Sequence`, each an entry of the one registry
:data:`gtvo.datasets.readers.READERS`. Layouts, association rules and frame conventions:
``docs/datasets.md``.

>>> seq = open_sequence("/data/KITTI/00")            # doctest: +SKIP
>>> validate(seq)                                    # doctest: +SKIP
"""

from __future__ import annotations

import importlib
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gtvo.core.paths import link_problem
from gtvo.datasets.readers import READERS, DatasetReader, reader_named, reader_taking
from gtvo.errors import InputError

if TYPE_CHECKING:
    from gtvo.config.sections.wheel import WheelReadOptions
    from gtvo.datasets.euroc import read_euroc
    from gtvo.datasets.imu_files import ImuReadOptions
    from gtvo.datasets.kitti import read_kitti
    from gtvo.datasets.kitti_raw import read_kitti_raw
    from gtvo.datasets.sequence import Sequence
    from gtvo.datasets.tum import TUM_INTRINSICS, read_tum

#: The readers' names this package offers, each imported from its module when first asked for
#: (``from gtvo.datasets import read_tum``): importing the package imports no reader.
_FROM_READERS = {"read_euroc": "gtvo.datasets.euroc", "read_kitti": "gtvo.datasets.kitti",
                 "read_kitti_raw": "gtvo.datasets.kitti_raw", "read_tum": "gtvo.datasets.tum",
                 "TUM_INTRINSICS": "gtvo.datasets.tum"}


def __getattr__(name: str) -> Any:
    module = _FROM_READERS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


#: ``"auto"`` or a name of :data:`FORMATS`.
DatasetFormat = str
#: The dataset layouts, the names of :data:`gtvo.datasets.readers.READERS` (every ``--format``'s choices).
FORMATS: tuple[str, ...] = tuple(reader.name for reader in READERS)

__all__ = ["DatasetFormat", "DatasetReader", "FORMATS", "READERS", "TUM_INTRINSICS", "detect_format",
           "open_sequence", "read_euroc", "read_kitti", "read_kitti_raw", "read_tum", "validate"]


def detect_format(path: str | Path) -> str:
    """The layout of a sequence folder or a ROS bag: the name of the first of
    :data:`gtvo.datasets.readers.READERS` whose ``looks_like`` accepts it.

    Raises:
        InputError: the path is missing, a file no reader takes, or matches no known layout.
    """
    from gtvo.datasets._common import require_dir  # noqa: PLC0415 - the readers' module (_FROM_READERS)

    where = Path(path)
    if not where.is_dir():  # a bag file (or a missing one, so that its reader says "not found")
        taken = next((r.name for r in READERS if r.looks_like(where)), None)
        if taken is not None:
            return taken
        if where.is_file():
            raise InputError("is a file, not a sequence folder or a ROS bag (a .bag file, or a ROS2 bag folder "
                             "with metadata.yaml)", path=path)
    folder = require_dir(where, "sequence folder")
    for reader in READERS:
        if reader.looks_like(folder):
            return reader.name
    broken = sorted(e for e in folder.iterdir() if link_problem(e) is not None)
    if broken:  # a file of the layout that cannot be followed is the cause, not an unknown layout
        raise InputError(f"{broken[0].name} is {link_problem(broken[0])}: the layout cannot be recognised",
                         path=folder)
    layouts = [r.layout for r in READERS]
    raise InputError(f"unknown dataset layout: expected {', '.join(layouts[:-1])}, or {layouts[-1]}", path=folder)


def open_sequence(path: str | Path, format: DatasetFormat = "auto",
                  camera: tuple[float, float, float, float] | None = None, max_frames: int | None = None,
                  ground_truth: str | Path | None = None, wheel_odometry: str | Path | None = None,
                  wheel_topic: str | None = None, wheel_options: WheelReadOptions | None = None,
                  imu: str | Path | None = None, imu_topic: str | None = None,
                  imu_options: ImuReadOptions | None = None, **bag_options: Any) -> Sequence:
    """Open a dataset folder as a lazy :class:`Sequence` (images are read when asked for), with the
    reader of its layout (:data:`gtvo.datasets.readers.READERS`).

    Args:
        path: the sequence folder.
        format: ``"auto"`` (see :func:`detect_format`) or one of :data:`FORMATS`.
        camera: ``(fx, fy, cx, cy)`` for TUM folders (overrides the name-based intrinsics).
        max_frames: keep only the first ``max_frames`` frames.
        ground_truth: a ground-truth file to use instead of the one in the folder (KITTI poses,
            KITTI raw OXTS folder, ASL csv or TUM trajectory, as the layout reads).
        wheel_odometry: a wheel odometry CSV to use (any format); without it a folder's
            ``wheel_odometry.csv`` when there is one, a bag's wheel topic (docs/wheel_odometry.md).
        wheel_topic: ROS bags only: the wheel odometry topic (``"none"``: none); default
            ``wheel_options.topic``, else the one candidate.
        wheel_options: how wheel readings become metres (the config's ``wheel:`` section,
            :meth:`gtvo.config.sections.wheel.WheelConfig.read_options`; default its defaults).
        imu: an IMU CSV to use (``time,wx,wy,wz,ax,ay,az`` or EuRoC's); without it the folder's
            ``imu0/data.csv`` (or ``mav0/imu0``), a bag's ``sensor_msgs/Imu`` topic (docs/imu.md).
        imu_topic: ROS bags only: the IMU topic (``"none"``: none); default ``imu_options.topic``,
            else the one candidate.
        imu_options: the config's ``imu:`` section (:func:`gtvo.datasets.imu_files.imu_read_options`;
            ``enabled=False``: no IMU, ``--no-imu``); default its defaults.
        bag_options: ROS bags only: ``calib``, ``left_topic``, ``right_topic``, ``depth_topic``,
            ``ground_truth_topic``, ``stamp_tolerance`` (:func:`gtvo.datasets.bag.read_bag`).

    Raises:
        InputError: an unknown format, an option the layout does not take, or the reader's errors.
    """
    from gtvo.datasets.imu import check_imu_clock  # noqa: PLC0415 - the readers' modules (_FROM_READERS)
    from gtvo.datasets.imu_files import ImuReadOptions, read_imu_folder  # noqa: PLC0415
    from gtvo.datasets.wheel_files import WHEEL_CSV, WheelReadOptions, read_wheel_csv  # noqa: PLC0415

    folder = Path(path)
    if max_frames is not None and int(max_frames) < 1:
        raise InputError(f"max_frames must be >= 1, got {max_frames}")
    reader = reader_named(detect_format(folder) if format == "auto" else format)
    options = _reader_options(reader, folder, {"camera": camera, **bag_options, "wheel_topic": wheel_topic,
                                               "imu_topic": imu_topic})
    wheel = wheel_options or WheelReadOptions()
    imu_read = imu_options or ImuReadOptions()
    if "imu_topic" in options:
        imu_read = replace(imu_read, topic=options.pop("imu_topic"))
    if imu is not None and not imu_read.enabled:
        raise InputError("--imu and --no-imu (imu.enabled: false) contradict each other", path=Path(imu))
    if reader.logs_wheels:
        if wheel_odometry is not None:
            options["wheel_topic"] = "none"  # the file replaces the log's topics
        options["wheel_options"] = wheel
    if reader.reads_imu:
        options["imu_options"] = imu_read
        if imu is not None:
            options["imu"] = Path(imu)
    seq = reader.read(folder, max_frames=None if max_frames is None else int(max_frames),
                      ground_truth=None if ground_truth is None else Path(ground_truth), **options)
    if wheel_odometry is None and not reader.logs_wheels and (folder / WHEEL_CSV).is_file():
        wheel_odometry = folder / WHEEL_CSV
    if wheel_odometry is not None:
        seq.wheel_odometry = read_wheel_csv(wheel_odometry, wheel)
    if not reader.reads_imu:  # the folder's imu0/data.csv (a KITTI-layout synthetic log writes one), or --imu
        seq.imu = read_imu_folder(folder, imu_read, csv=None if imu is None else Path(imu))
    if seq.imu is not None:
        check_imu_clock(seq.imu, seq.timestamps)
    return seq


def _reader_options(reader: DatasetReader, path: Path, given: dict[str, Any]) -> dict[str, Any]:
    """The options given (not None) that ``reader`` takes.

    Raises:
        InputError: one of them belongs to another layout (naming the options and that layout).
        TypeError: no reader takes it.
    """
    given = {k: v for k, v in given.items() if v is not None}
    for name in given:
        owner = reader_taking(name)
        if owner is None:
            raise TypeError(f"open_sequence() got an unexpected keyword argument {name!r}")
        if owner is not reader:
            theirs = [k for k in given if k in owner.options]
            raise InputError(f"{', '.join(theirs)} apply to {owner.title} only, this is {reader.name}", path=path)
    return given


def validate(seq: Sequence, check_images: bool = True, progress: bool = True) -> None:
    """Load every frame's images once; raise the first :class:`InputError` (naming its file).

    Args:
        seq: the sequence.
        check_images: when False, nothing is loaded (only the up-front checks ``Sequence`` did).
        progress: show a tqdm progress bar.
    """
    if not check_images:
        return
    from tqdm import tqdm  # noqa: PLC0415

    for i in tqdm(range(len(seq)), desc=f"checking {seq.name}", unit="frame", disable=not progress):
        seq.left(i)
        if seq.kind == "stereo":
            seq.right(i)
        else:
            seq.depth(i)
