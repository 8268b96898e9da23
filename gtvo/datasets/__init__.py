"""Dataset readers: KITTI odometry, KITTI raw, EuRoC MAV (ASL) and TUM RGB-D folders as a lazy
:class:`gtvo.datasets.sequence.Sequence`. Layouts, association rules and frame conventions:
``docs/datasets.md``.

>>> seq = open_sequence("/data/KITTI/00")            # doctest: +SKIP
>>> validate(seq)                                    # doctest: +SKIP
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, Literal

from tqdm import tqdm

from gtvo.datasets._common import require_dir
from gtvo.datasets.bag import looks_like_bag, read_bag
from gtvo.datasets.euroc import looks_like_euroc, read_euroc
from gtvo.datasets.kitti import looks_like_kitti, read_kitti
from gtvo.datasets.kitti_raw import looks_like_kitti_raw, read_kitti_raw
from gtvo.datasets.tum import TUM_INTRINSICS, looks_like_tum, read_tum
from gtvo.errors import InputError
from gtvo.datasets.sequence import Sequence
from gtvo.datasets.imu import check_imu_clock
from gtvo.datasets.imu_files import ImuReadOptions, read_imu_folder
from gtvo.datasets.wheel_files import WHEEL_CSV, WheelReadOptions, read_wheel_csv

DatasetFormat = Literal["auto", "kitti", "kitti_raw", "euroc", "tum", "bag"]
FORMATS: tuple[str, ...] = ("kitti", "kitti_raw", "euroc", "tum", "bag")

__all__ = ["DatasetFormat", "FORMATS", "TUM_INTRINSICS", "detect_format", "open_sequence", "read_euroc",
           "read_kitti", "read_kitti_raw", "read_tum", "validate"]


def detect_format(path: str | Path) -> str:
    """The layout of a sequence folder: ``"kitti"``, ``"kitti_raw"``, ``"euroc"`` or ``"tum"``;
    ``"bag"`` for a ROS bag.

    Raises:
        InputError: the folder is missing or matches no known layout.
    """
    if looks_like_bag(Path(path)):
        return "bag"
    if Path(path).is_file():
        raise InputError("is a file, not a sequence folder or a ROS bag (a .bag file, or a ROS2 bag folder with "
                         "metadata.yaml)", path=path)
    folder = require_dir(Path(path), "sequence folder")
    if looks_like_kitti(folder):
        return "kitti"
    if looks_like_kitti_raw(folder):
        return "kitti_raw"
    if looks_like_euroc(folder):
        return "euroc"
    if looks_like_tum(folder):
        return "tum"
    raise InputError("unknown dataset layout: expected KITTI (calib.txt + image_0/ or image_l/), KITTI raw "
                     "(image_00/data/ + calib_cam_to_cam.txt), EuRoC (mav0/cam0/ + mav0/cam1/), TUM RGB-D "
                     "(rgb.txt + depth.txt), or a ROS bag (a .bag file, or a ROS2 bag folder with metadata.yaml "
                     "and its .db3 or .mcap files)", path=folder)


def open_sequence(path: str | Path, format: DatasetFormat = "auto",
                  camera: tuple[float, float, float, float] | None = None, max_frames: int | None = None,
                  ground_truth: str | Path | None = None, wheel_odometry: str | Path | None = None,
                  wheel_topic: str | None = None, wheel_options: WheelReadOptions | None = None,
                  imu: str | Path | None = None, imu_topic: str | None = None,
                  imu_options: ImuReadOptions | None = None, **bag_options: Any) -> Sequence:
    """Open a dataset folder as a lazy :class:`Sequence` (images are read when asked for).

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
            :meth:`gtvo.config.wheel.WheelConfig.read_options`; default its defaults).
        imu: an IMU CSV to use (``time,wx,wy,wz,ax,ay,az`` or EuRoC's); without it the folder's
            ``imu0/data.csv`` (or ``mav0/imu0``), a bag's ``sensor_msgs/Imu`` topic (docs/imu.md).
        imu_topic: ROS bags only: the IMU topic (``"none"``: none); default ``imu_options.topic``,
            else the one candidate.
        imu_options: the config's ``imu:`` section (:meth:`gtvo.config.imu.ImuConfig.read_options`;
            ``enabled=False``: no IMU, ``--no-imu``); default its defaults.
        bag_options: ROS bags only: ``calib``, ``left_topic``, ``right_topic``, ``depth_topic``,
            ``ground_truth_topic``, ``stamp_tolerance`` (:func:`gtvo.datasets.bag.read_bag`).
    """
    folder = Path(path)
    if max_frames is not None and int(max_frames) < 1:
        raise InputError(f"max_frames must be >= 1, got {max_frames}")
    if format not in ("auto",) + FORMATS:
        raise InputError(f"unknown dataset format {format!r}: choose auto, {', '.join(FORMATS)}")
    kind = detect_format(folder) if format == "auto" else format
    if camera is not None and kind != "tum":
        raise InputError(f"a camera override applies to TUM folders only, this is {kind}", path=folder)
    gt = None if ground_truth is None else Path(ground_truth)
    n = None if max_frames is None else int(max_frames)
    bag_options = {k: v for k, v in bag_options.items() if v is not None}
    if wheel_topic is not None:
        bag_options["wheel_topic"] = wheel_topic
    wheel = wheel_options or WheelReadOptions()
    imu_read = imu_options or ImuReadOptions()
    if imu_topic is not None:
        if kind != "bag":
            raise InputError(f"--imu-topic applies to ROS bags only, this is {kind}", path=folder)
        imu_read = replace(imu_read, topic=imu_topic)
    if imu is not None and not imu_read.enabled:
        raise InputError("--imu and --no-imu (imu.enabled: false) contradict each other", path=Path(imu))
    if kind == "bag":
        bag_options["imu_options"] = replace(imu_read, topic="none") if imu is not None else imu_read
    if kind == "bag" or bag_options:
        if wheel_odometry is not None:
            bag_options["wheel_topic"] = "none"  # the file replaces the bag's topics
        seq = _open_bag(folder, kind, n, gt, {**bag_options, "wheel_options": wheel})
    elif kind == "kitti":
        seq = read_kitti(folder, max_frames=n, ground_truth=gt)
    elif kind == "kitti_raw":
        seq = read_kitti_raw(folder, max_frames=n, ground_truth=gt)
    elif kind == "euroc":
        seq = read_euroc(folder, max_frames=n, ground_truth=gt, imu_options=imu_read,
                         imu=None if imu is None else Path(imu))
    else:
        seq = read_tum(folder, max_frames=n, camera=camera, ground_truth=gt)
    if wheel_odometry is None and kind != "bag" and (folder / WHEEL_CSV).is_file():
        wheel_odometry = folder / WHEEL_CSV
    if wheel_odometry is not None:
        seq.wheel_odometry = read_wheel_csv(wheel_odometry, wheel)
    if kind not in ("bag", "euroc") or (kind == "bag" and imu is not None):
        base = folder if kind != "bag" or folder.is_dir() else folder.parent
        seq.imu = read_imu_folder(base, imu_read, csv=None if imu is None else Path(imu))
    if seq.imu is not None:
        check_imu_clock(seq.imu, seq.timestamps)
    return seq


def _open_bag(path: Path, kind: str, max_frames: int | None, ground_truth: Path | None,
              options: dict[str, Any]) -> Sequence:
    if kind != "bag":
        given = [k for k in options if k not in ("wheel_options", "imu_options")]
        raise InputError(f"{', '.join(given)} apply to ROS bags only, this is {kind}", path=path)
    if not looks_like_bag(path):
        raise InputError("not a ROS bag: expected a .bag file or a ROS2 bag folder (metadata.yaml)", path=path)
    calib = options.pop("calib", None)
    return read_bag(path, max_frames=max_frames, calib=None if calib is None else Path(calib),
                    ground_truth=ground_truth, **options)


def validate(seq: Sequence, check_images: bool = True, progress: bool = True) -> None:
    """Load every frame's images once; raise the first :class:`InputError` (naming its file).

    Args:
        seq: the sequence.
        check_images: when False, nothing is loaded (only the up-front checks ``Sequence`` did).
        progress: show a tqdm progress bar.
    """
    if not check_images:
        return
    for i in tqdm(range(len(seq)), desc=f"checking {seq.name}", unit="frame", disable=not progress):
        seq.left(i)
        if seq.kind == "stereo":
            seq.right(i)
        else:
            seq.depth(i)
