"""The registry of dataset readers: one entry per layout, the one list every ``--format`` uses.

:data:`READERS` is the only place the dataset layouts are listed. :func:`gtvo.datasets.detect_format`
asks each entry, in this order, whether a path looks like its layout;
:func:`gtvo.datasets.open_sequence` calls the entry's ``read``; :data:`gtvo.datasets.FORMATS`, the
``--format`` choices of ``gtvo run``, ``gtvo info`` and ``gtvo loops``, the ``format:`` key of a
``gtvo batch`` list and the unknown-layout error are all made from it.

Adding a reader is one entry. Write ``gtvo/datasets/NAME.py`` with

* ``looks_like_NAME(path: Path) -> bool``: True when ``path`` has the layout's marker files
  (cheap: file names only, no file read), and
* ``read_NAME(path: Path, max_frames: int | None = None, ground_truth: Path | None = None) ->
  Sequence``: a lazy :class:`gtvo.datasets.sequence.Sequence` whose image loaders return
  float32 gray images (:class:`gtvo.datasets._common.GrayImageLoader` does this for image files)
  and raise :class:`gtvo.errors.InputError` naming the file for bad input,

then add ``DatasetReader("NAME", "Title (marker files)", "NAME folders",
ReaderFunction("gtvo.datasets.NAME", "looks_like_NAME"), ReaderFunction("gtvo.datasets.NAME", "read_NAME"))``
to :data:`READERS` (its module is imported when they are first called; detection tries the entries
in order: put it before a layout whose test its folders would also pass). Every command then accepts
``--format NAME``, detects the layout and lists it in the unknown-layout error (``tests/test_datasets.py`` checks that every
command offers the same formats and that no other reader claims a layout's folder); describe the
layout in ``docs/datasets.md``. A reader with options of its own names them in ``options``
(keyword arguments of ``open_sequence``, refused for the other layouts).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from gtvo.errors import InputError

if TYPE_CHECKING:
    from gtvo.datasets.sequence import Sequence

#: ``open_sequence``'s options for ROS bags (:func:`gtvo.datasets.bag.read_bag`).
BAG_OPTIONS: tuple[str, ...] = ("calib", "left_topic", "right_topic", "depth_topic", "ground_truth_topic",
                                "stamp_tolerance", "wheel_topic", "imu_topic")


@dataclass(frozen=True)
class ReaderFunction:
    """A function of a reader's module, imported when it is first called: a run imports the module of
    its own layout (and of the layouts detection tried before it), not every reader's (a bag reader's
    imports are not a KITTI run's start-up). Called like the function ``module.name`` itself."""

    module: str
    name: str

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return getattr(importlib.import_module(self.module), self.name)(*args, **kwargs)


@dataclass(frozen=True)
class DatasetReader:
    """One dataset layout :func:`gtvo.datasets.open_sequence` reads.

    Attributes:
        name: the ``--format`` value, also the report's ``input.format``.
        layout: what marks the layout, for the unknown-layout error (``"KITTI (calib.txt + ...)"``).
        title: what its logs are called in errors (``"TUM folders"``: "camera apply to TUM folders only").
        looks_like: ``looks_like(path) -> bool``, :func:`gtvo.datasets.detect_format`'s test.
        read: ``read(path, max_frames=..., ground_truth=..., **options) -> Sequence``.
        options: the keyword options of ``open_sequence`` only this layout takes (passed to ``read``
            when given).
        logs_wheels: the log itself carries the wheel odometry (a bag's topics): ``read`` also takes
            ``wheel_options``, and no ``wheel_odometry.csv`` is looked for beside it.
        reads_imu: the reader reads the log's IMU itself (EuRoC's ``mav0/imu0``, a bag's
            ``sensor_msgs/Imu`` topic): ``read`` also takes ``imu_options``
            (:class:`gtvo.datasets.imu_files.ImuReadOptions`) and ``imu`` (an IMU CSV to use instead).
            The other layouts get the folder's ``imu0/data.csv`` (or ``imu``) from ``open_sequence``.
    """

    name: str
    layout: str
    title: str
    looks_like: Callable[[Path], bool]
    read: Callable[..., Sequence]
    options: tuple[str, ...] = ()
    logs_wheels: bool = False
    reads_imu: bool = False


def read_bag_log(path: Path, max_frames: int | None = None, ground_truth: Path | None = None,
                 calib: str | Path | None = None, imu: Path | None = None, **options: Any) -> Sequence:
    """:func:`gtvo.datasets.bag.read_bag` for ``open_sequence`` (also when ``format="bag"`` is given
    for a path that is not one); ``imu``: an IMU CSV that replaces the bag's IMU topics.

    Raises:
        InputError: ``path`` is not a ROS bag, or the bag's own errors.
    """
    from gtvo.datasets.bag import looks_like_bag, read_bag  # noqa: PLC0415 - see ReaderFunction
    from gtvo.datasets.imu_files import ImuReadOptions, read_imu_folder  # noqa: PLC0415

    if not looks_like_bag(path):
        raise InputError("not a ROS bag: expected a .bag file or a ROS2 bag folder (metadata.yaml)", path=path)
    imu_options = options.get("imu_options") or ImuReadOptions()
    if imu is not None:
        options["imu_options"] = replace(imu_options, topic="none")  # the file replaces the bag's topics
    seq = read_bag(path, max_frames=max_frames, calib=None if calib is None else Path(calib),
                   ground_truth=ground_truth, **options)
    if imu is not None:
        seq.imu = read_imu_folder(path if path.is_dir() else path.parent, imu_options, csv=imu)
    return seq


#: Every layout, in the order :func:`gtvo.datasets.detect_format` tries them (a path that is not a
#: folder can only be a bag file).
READERS: tuple[DatasetReader, ...] = (
    DatasetReader("kitti", "KITTI (calib.txt + image_0/ or image_l/)", "KITTI odometry folders",
                  ReaderFunction("gtvo.datasets.kitti", "looks_like_kitti"),
                  ReaderFunction("gtvo.datasets.kitti", "read_kitti")),
    DatasetReader("kitti_raw", "KITTI raw (image_00/data/ + calib_cam_to_cam.txt)", "KITTI raw drives",
                  ReaderFunction("gtvo.datasets.kitti_raw", "looks_like_kitti_raw"),
                  ReaderFunction("gtvo.datasets.kitti_raw", "read_kitti_raw")),
    DatasetReader("euroc", "EuRoC (mav0/cam0/ + mav0/cam1/)", "EuRoC folders",
                  ReaderFunction("gtvo.datasets.euroc", "looks_like_euroc"),
                  ReaderFunction("gtvo.datasets.euroc", "read_euroc"), reads_imu=True),
    DatasetReader("tum", "TUM RGB-D (rgb.txt + depth.txt)", "TUM folders",
                  ReaderFunction("gtvo.datasets.tum", "looks_like_tum"),
                  ReaderFunction("gtvo.datasets.tum", "read_tum"), ("camera",)),
    DatasetReader("bag", "a ROS bag (a .bag file, or a ROS2 bag folder with metadata.yaml and its .db3 or "
                         ".mcap files)", "ROS bags", ReaderFunction("gtvo.datasets.bag", "looks_like_bag"),
                  read_bag_log, BAG_OPTIONS, logs_wheels=True, reads_imu=True),
)


def reader_named(name: str) -> DatasetReader:
    """The entry of :data:`READERS` called ``name``.

    Raises:
        InputError: no reader has that name (the message lists the formats).
    """
    for reader in READERS:
        if reader.name == name:
            return reader
    raise InputError(f"unknown dataset format {name!r}: choose auto, {', '.join(r.name for r in READERS)}")


def reader_taking(option: str) -> DatasetReader | None:
    """The reader whose ``options`` include ``option`` (None: no reader's)."""
    return next((r for r in READERS if option in r.options), None)
