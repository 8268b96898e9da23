"""KITTI raw drives ("synced + rectified"), as KITTI distributes them.

::

    <drive>/image_00/data/*.png, image_01/data/   left / right rectified gray images, same names
                                                   (without them the colour pair image_02/, image_03/)
    <drive>/image_00/timestamps.txt                one "YYYY-MM-DD hh:mm:ss.nnnnnnnnn" per image
    calib_cam_to_cam.txt                           P_rect_00 .. P_rect_03, R_rect_00 (3x3), ...
    calib_imu_to_velo.txt, calib_velo_to_cam.txt   R (3x3), T (3): x_velo = R x_imu + T,
                                                   x_cam0 = R x_velo + T (unrectified cam0)
    <drive>/oxts/data/*.txt                        optional GPS/INS record per image (same names):
                                                   lat lon alt roll pitch yaw ... (30 fields)

The calibration files are read from the drive folder, else from the folder above it (KITTI's own
layout: ``DATE/calib_*.txt`` beside ``DATE/DATE_drive_XXXX_sync/``).

Ground truth (when ``oxts/`` exists), as the KITTI devkit's ``convertOxtsToPose``:

* Mercator scale ``s = cos(lat_0)`` from the first record; ``t = (s lon er pi/180,
  s er log(tan((90 + lat) pi/360)), alt)`` with ``er = 6378137 m``; ``R = Rz(yaw) Ry(pitch)
  Rx(roll)``; ``T_w_imu_i = inv(T_0) T_i`` (the world is the IMU at the first record).
* ``T_cam0_imu = T_cam0_velo T_velo_imu``; the rectified cam0 is ``x_rect0 = R_rect_00 x_cam0``, so
  ``T_w_rect0 = T_w_imu inv(T_cam0_imu) [R_rect_00^T | 0]``.
* A rectified camera i is the rectified cam0 moved by ``t_i = K^-1 P_rect_0i[:, 3]``
  (``x_i = x_rect0 + t_i``, as in :mod:`gtvo.datasets.kitti`): ``T_w_left = T_w_rect0 [I | -t_left]``
  (the colour pair's left camera is cam2).

Derivation and conventions: ``docs/datasets.md``.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.core.lie import rotation_block_error
from gtvo.datasets._common import (FloatArray, GrayImageLoader, TextRow, image_size, parse_floats, read_rows,
                                   require_dir, require_file)
from gtvo.datasets.kitti import DEFAULT_PERIOD_S, IMAGE_SUFFIXES
from gtvo.datasets.kitti import rectified_pair  # the same P-matrix rules as KITTI odometry
from gtvo.errors import InputError
from gtvo.datasets.sequence import Sequence

#: (left, right) camera folders tried in order, with their rectified projection matrices.
CAMERA_DIRS: tuple[tuple[str, str, str, str], ...] = (("image_00", "image_01", "P_rect_00", "P_rect_01"),
                                                      ("image_02", "image_03", "P_rect_02", "P_rect_03"))
CAM_TO_CAM = "calib_cam_to_cam.txt"
IMU_TO_VELO = "calib_imu_to_velo.txt"
VELO_TO_CAM = "calib_velo_to_cam.txt"
#: Earth radius of the devkit's Mercator projection (m).
EARTH_RADIUS_M = 6378137.0


def looks_like_kitti_raw(path: Path) -> bool:
    """True when ``path`` has ``image_00/data`` (or ``image_02/data``) and a ``calib_cam_to_cam.txt``
    beside it or in the folder above."""
    has_images = any((path / d[0] / "data").is_dir() for d in CAMERA_DIRS)
    return has_images and calibration_file(path, CAM_TO_CAM) is not None


def calibration_file(drive: Path, name: str) -> Path | None:
    """``drive/name``, else ``drive/../name`` (KITTI's date folder), else None."""
    for folder in (drive, drive.resolve().parent):
        if (folder / name).is_file():
            return folder / name
    return None


def _require_calibration(drive: Path, name: str) -> Path:
    path = calibration_file(drive, name)
    if path is None:
        raise InputError(f"{name} not found in the drive folder or the folder above it", path=drive)
    return path


# --------------------------------------------------------------------------------------------
# calibration files

def read_labelled(path: Path) -> dict[str, TextRow]:
    """The ``name: v1 v2 ...`` lines of a KITTI raw calibration file, by name (fields without it)."""
    rows = read_rows(require_file(path, "calibration file"), 1)
    return {r.fields[0].rstrip(":"): TextRow(r.line, r.fields[1:]) for r in rows if r.fields[0].endswith(":")}


def labelled_values(path: Path, table: dict[str, TextRow], name: str, count: int) -> FloatArray:
    """``count`` finite numbers of the line ``name`` of a labelled calibration file."""
    if name not in table:
        raise InputError(f"no {name} line", path=path)
    row = table[name]
    if len(row.fields) != count:
        raise InputError(f"{name} needs {count} numbers, got {len(row.fields)}", path=path, line=row.line)
    return parse_floats(row, path)


def read_rigid(path: Path) -> FloatArray:
    """The 4x4 transform ``[R | T]`` of a ``calib_imu_to_velo.txt`` / ``calib_velo_to_cam.txt``
    (maps points of the first frame into the second); R must be a rotation."""
    table = read_labelled(path)
    T = np.eye(4)
    T[:3, :3] = labelled_values(path, table, "R", 9).reshape(3, 3)
    T[:3, 3] = labelled_values(path, table, "T", 3)
    _require_rotation(T[:3, :3], path, "R")
    return T


def read_rectifying_rotation(path: Path) -> FloatArray:
    """``R_rect_00`` of ``calib_cam_to_cam.txt`` as a 4x4 transform (``x_rect0 = R_rect_00 x_cam0``)."""
    T = np.eye(4)
    T[:3, :3] = labelled_values(path, read_labelled(path), "R_rect_00", 9).reshape(3, 3)
    _require_rotation(T[:3, :3], path, "R_rect_00")
    return T


def _require_rotation(R: FloatArray, path: Path, name: str) -> None:
    """KITTI prints 7 digits: a block off a rotation (:func:`gtvo.core.lie.rotation_block_error`)
    is bad input naming the file and the matrix."""
    problem = rotation_block_error(R)
    if problem is not None:
        raise InputError(f"{name} {problem}", path=path)


# --------------------------------------------------------------------------------------------
# timestamps and OXTS

def parse_kitti_time(text: str, path: Path, line: int) -> float:
    """``YYYY-MM-DD hh:mm:ss.nnnnnnnnn`` (read as UTC) in Unix seconds, nanoseconds kept to
    float64's resolution (about 0.24 us at today's times)."""
    stamp = text.strip()
    whole, _, fraction = stamp.partition(".")
    try:
        moment = datetime.strptime(whole, "%Y-%m-%d %H:%M:%S").replace(tzinfo=timezone.utc)
        frac = float(f"0.{fraction}") if fraction else 0.0
        if fraction and not fraction.isdigit():
            raise ValueError(fraction)
    except ValueError:
        raise InputError(f"not a KITTI timestamp (YYYY-MM-DD hh:mm:ss.nnnnnnnnn): {stamp!r}", path=path,
                         line=line) from None
    return moment.timestamp() + frac


def read_timestamps(path: Path, count: int) -> FloatArray:
    """One Unix time per image from a camera's ``timestamps.txt``; strictly increasing."""
    rows = read_rows(path, 2)
    if len(rows) != count:
        raise InputError(f"{len(rows)} timestamps for {count} images: one line per image", path=path)
    times = np.array([parse_kitti_time(" ".join(r.fields), path, r.line) for r in rows])
    back = np.flatnonzero(np.diff(times) <= 0)
    if back.size:
        raise InputError("timestamps are not strictly increasing", path=path, line=rows[back[0] + 1].line)
    return times


def oxts_pose(lat: float, lon: float, alt: float, roll: float, pitch: float, yaw: float,
              scale: float) -> FloatArray:
    """The devkit's un-normalised IMU pose (4x4) of one OXTS record (degrees for lat/lon, radians
    for the angles): Mercator ``(x, y)`` at ``scale``, altitude ``z``, ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Ry @ Rx
    T[0, 3] = scale * np.radians(lon) * EARTH_RADIUS_M
    T[1, 3] = scale * EARTH_RADIUS_M * np.log(np.tan(np.radians(90.0 + lat) / 2.0))
    T[2, 3] = alt
    return T


def read_oxts_record(path: Path) -> FloatArray:
    """The first six fields of an OXTS record: lat, lon (deg), alt (m), roll, pitch, yaw (rad)."""
    rows = read_rows(path, 6)
    if len(rows) != 1:
        raise InputError(f"an OXTS record is one line, got {len(rows)}", path=path)
    values = parse_floats(rows[0], path, slice(0, 6))
    if not -90.0 < values[0] < 90.0:
        raise InputError(f"latitude {float(values[0])!r} outside (-90, 90) degrees", path=path, line=rows[0].line)
    return values


def oxts_imu_poses(records: list[Path | None]) -> FloatArray:
    """``T_w_imu`` (N, 4, 4) of the records as the devkit's ``convertOxtsToPose``: scale and
    world from the first record; NaN rows where a record is missing (None)."""
    out = np.full((len(records), 4, 4), np.nan)
    scale, T0_inv = None, None
    for i, path in enumerate(records):
        if path is None:
            continue
        lat, lon, alt, roll, pitch, yaw = read_oxts_record(path)
        if scale is None:
            scale = float(np.cos(np.radians(lat)))
        T = oxts_pose(lat, lon, alt, roll, pitch, yaw, scale)
        if T0_inv is None:
            T0_inv = np.linalg.inv(T)
        out[i] = T0_inv @ T
    return out


def camera_ground_truth(T_w_imu: FloatArray, T_cam0_imu: FloatArray, R_rect_00: FloatArray,
                        t_left: FloatArray) -> FloatArray:
    """``T_w_left = T_w_imu inv(T_cam0_imu) inv(R_rect_00) [I | -t_left]`` for (N, 4, 4) IMU poses
    (NaN rows stay NaN)."""
    T_left_rect0 = np.eye(4)
    T_left_rect0[:3, 3] = t_left  # x_left = x_rect0 + t_left
    T_imu_left = np.linalg.inv(T_left_rect0 @ R_rect_00 @ T_cam0_imu)
    return T_w_imu @ T_imu_left


# --------------------------------------------------------------------------------------------
# the reader

def _camera_dirs(root: Path) -> tuple[Path, Path, tuple[str, str]]:
    for left, right, p_left, p_right in CAMERA_DIRS:
        if (root / left / "data").is_dir():
            return root / left, require_dir(root / right / "data", "right image folder").parent, (p_left, p_right)
    raise InputError(f"no left image folder ({', '.join(d[0] + '/data' for d in CAMERA_DIRS)})", path=root)


def _ground_truth(root: Path, oxts_dir: Path, lefts: list[Path], t_left: FloatArray) -> FloatArray:
    """The left camera's poses from ``oxts_dir/data/<image name>.txt`` (NaN where missing)."""
    data = require_dir(oxts_dir / "data", "OXTS data folder")
    records = [data / f"{p.stem}.txt" for p in lefts]
    found = [p if p.is_file() else None for p in records]
    if not any(found):
        raise InputError(f"no OXTS record named like the images ({records[0].name}, ...)", path=data)
    cam_to_cam = _require_calibration(root, CAM_TO_CAM)
    T_cam0_velo = read_rigid(_require_calibration(root, VELO_TO_CAM))
    T_cam0_imu = T_cam0_velo @ read_rigid(_require_calibration(root, IMU_TO_VELO))
    return camera_ground_truth(oxts_imu_poses(found), T_cam0_imu, read_rectifying_rotation(cam_to_cam), t_left)


def read_kitti_raw(root: Path, max_frames: int | None = None, ground_truth: Path | None = None) -> Sequence:
    """Open a KITTI raw drive folder (see the module docstring for the layout).

    Args:
        root: the drive folder (``..._drive_XXXX_sync``).
        max_frames: keep only the first frames.
        ground_truth: an OXTS folder (with ``data/*.txt``) to use instead of ``root/oxts``.
    """
    require_dir(root, "KITTI raw drive folder")
    left_dir, right_dir, cameras = _camera_dirs(root)
    cam_to_cam = _require_calibration(root, CAM_TO_CAM)
    K, baseline, t_left = rectified_pair(cam_to_cam, cameras)
    lefts = sorted(p for p in (left_dir / "data").iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not lefts:
        raise InputError("empty sequence: no images", path=left_dir / "data")
    count = len(lefts)
    n = count if max_frames is None else min(count, int(max_frames))
    rights = [right_dir / "data" / p.name for p in lefts]
    for left, right in zip(lefts[:n], rights[:n]):
        if not right.is_file():
            raise InputError(f"missing right image for left image {left}", path=right)
    stamps = left_dir / "timestamps.txt"
    times = read_timestamps(stamps, count) if stamps.exists() else DEFAULT_PERIOD_S * np.arange(count)
    oxts = ground_truth if ground_truth is not None else root / "oxts"
    poses = _ground_truth(root, oxts, lefts, t_left) if (ground_truth is not None or oxts.is_dir()) else None
    width, height = image_size(lefts[0])
    try:
        camera = StereoCamera(PinholeCamera.from_matrix(K, width, height), baseline)
    except InputError as exc:
        raise InputError(f"{exc} (from {cameras[0]})", path=cam_to_cam) from None
    shape = (height, width)
    return Sequence(
        name=root.resolve().name, kind="stereo", camera=camera, timestamps=times[:n],
        load_left=GrayImageLoader(lefts[:n], shape, "left"), load_right=GrayImageLoader(rights[:n], shape, "right"),
        gt_poses=None if poses is None else poses[:n], source=root, frame_names=[str(p) for p in lefts[:n]])
