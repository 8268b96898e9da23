"""EuRoC MAV (ASL) layout: a raw, distorted stereo pair that we rectify on load.

::

    <seq>/mav0/cam0/sensor.yaml     T_BS (cam0 -> body), resolution, intrinsics [fu fv cu cv],
                                    radial-tangential distortion [k1 k2 p1 p2]
    <seq>/mav0/cam0/data.csv        "#timestamp [ns],filename"
    <seq>/mav0/cam0/data/<ns>.png   raw left images; cam1/ the same for the right camera
    <seq>/mav0/state_groundtruth_estimate0/data.csv   optional ground truth (ns, p xyz, q wxyz, ...)
    <seq>/*groundtruth*.csv|.txt    else a ground-truth csv (same columns) or TUM file beside mav0/

Left and right images are paired by equal timestamps (within :data:`STEREO_TOLERANCE_NS`).
Ground truth (the body/IMU pose ``T_W_B``) is interpolated at the image times (see
:func:`gtvo.datasets._common.interpolate_poses`) and carried to the rectified left camera:
``T_W_rect = T_W_B * T_BS(cam0) * T_cam0_rect``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gtvo.datasets._common import (FloatArray, GrayImageLoader, image_size, interpolate_poses, nearest_indices,
                                   parse_timestamp_ns,
                                   read_rows, read_trajectory, require_dir, require_file, require_overlap)
from gtvo.errors import InputError, show
from gtvo.datasets.imu_files import ImuReadOptions, load_yaml_mapping, read_imu_folder
from gtvo.datasets.rectify import RawCamera, StereoRectification, stereo_rectification
from gtvo.datasets.sequence import Sequence
from gtvo.core.lie import rotation_block_error

#: Left and right image timestamps closer than this (ns) form a pair.
STEREO_TOLERANCE_NS = 1_000_000
#: A frame further than this (s) from every ground-truth sample gets no pose (unless interpolated).
GT_TOLERANCE_S = 0.02
#: Ground truth is interpolated between samples at most this far apart (s).
GT_MAX_GAP_S = 0.1


def find_mav0(path: Path) -> Path | None:
    """The ``mav0`` folder of a sequence given as its root or as ``mav0`` itself."""
    for candidate in (path / "mav0", path):
        if (candidate / "cam0").is_dir() and (candidate / "cam1").is_dir():
            return candidate
    return None


def looks_like_euroc(path: Path) -> bool:
    """True when ``path`` (or its ``mav0``) has cam0/ and cam1/ folders."""
    return find_mav0(path) is not None


def _load_yaml(path: Path) -> dict:
    """A sensor.yaml's mapping (:func:`gtvo.datasets.imu_files.load_yaml_mapping`: OpenCV's
    ``%YAML:1.0`` directive, which PyYAML rejects, is dropped)."""
    return load_yaml_mapping(path, "sensor.yaml")


def _yaml_numbers(data: dict, key: str, count: int, path: Path) -> FloatArray:
    """``count`` finite numbers under ``key`` (a list, or a matrix mapping with ``data``)."""
    if key not in data:
        raise InputError(f"no {key!r} key (it needs {count} numbers)", path=path)
    value = data[key]
    if isinstance(value, dict):
        if "data" not in value:
            raise InputError(f"{key} has no 'data' key (it needs {count} numbers)", path=path)
        value = value["data"]
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{key} must be a list of numbers, got {value!r}", path=path) from None
    if arr.size != count:
        raise InputError(f"{key} needs {count} numbers, got {arr.size}", path=path)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{key} contains NaN or infinite values", path=path)
    return arr


def read_sensor_yaml(path: Path) -> tuple[RawCamera, FloatArray]:
    """``(raw camera, T_BS)`` from an ASL camera ``sensor.yaml``."""
    data = _load_yaml(require_file(path, "camera sensor.yaml"))

    def numbers(key: str, count: int) -> FloatArray:
        return _yaml_numbers(data, key, count, path)

    model = data.get("camera_model", "pinhole")
    if model != "pinhole":
        raise InputError(f"camera_model {model!r} is not supported (only pinhole)", path=path)
    distortion_model = data.get("distortion_model", "radial-tangential")
    if distortion_model not in ("radial-tangential", "radtan"):
        raise InputError(f"distortion_model {distortion_model!r} is not supported (only radial-tangential)", path=path)
    T_BS = _rigid_T_BS(numbers("T_BS", 16), path)
    width, height = numbers("resolution", 2)
    fu, fv, cu, cv = numbers("intrinsics", 4)
    distortion = numbers("distortion_coefficients", 4)
    if width != int(width) or height != int(height):
        raise InputError(f"resolution must be two whole numbers of pixels, got {show([width, height])}", path=path)
    if not (fu > 0 and fv > 0 and width >= 1 and height >= 1):
        raise InputError(f"invalid intrinsics {show([fu, fv, cu, cv])} or resolution {show([width, height])}", path=path)
    K = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    return RawCamera(K, distortion, int(width), int(height)), T_BS


def _rigid_T_BS(values: FloatArray, path: Path) -> FloatArray:
    """``T_BS`` as a 4x4 rigid transform, or a one-line :class:`InputError` naming ``path``: the
    bottom row must be ``0 0 0 1`` and the rotation block a rotation
    (:func:`gtvo.core.lie.rotation_block_error`; EuRoC's files: 6e-13 off)."""
    T = np.asarray(values, dtype=np.float64).reshape(4, 4)
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=1e-9):
        raise InputError(f"T_BS bottom row is {T[3].tolist()}, expected [0, 0, 0, 1]", path=path)
    problem = rotation_block_error(T[:3, :3])
    if problem is not None:
        raise InputError(f"T_BS rotation block {problem}", path=path)
    return T


def read_image_list(cam_dir: Path) -> tuple[np.ndarray, list[Path]]:
    """``(ns timestamps, image paths)`` of an ASL camera folder, from its data.csv."""
    csv = cam_dir / "data.csv"
    rows = read_rows(csv, 2, delimiter=",")
    ns = np.array([parse_timestamp_ns(r.fields[0], csv, r.line) for r in rows], dtype=np.int64)
    paths = [cam_dir / "data" / r.fields[1] for r in rows]
    return ns, paths


class RectifiedLoader(GrayImageLoader):
    """Loads a raw image lazily and warps it into the rectified frame."""

    def __init__(self, paths: list[Path], shape: tuple[int, int], what: str, rectification: StereoRectification):
        super().__init__(paths, shape, what)
        self.rectify = rectification.rectify_left if what == "left" else rectification.rectify_right

    def __call__(self, i: int) -> np.ndarray:
        return self.rectify(super().__call__(i))


def _pair_stereo(mav0: Path, max_frames: int | None) -> tuple[np.ndarray, list[Path], list[Path]]:
    """Left timestamps and (left, right) image paths, cut to ``max_frames``; every left needs a right."""
    left_ns, lefts = read_image_list(require_dir(mav0 / "cam0", "cam0 folder"))
    right_ns, rights = read_image_list(require_dir(mav0 / "cam1", "cam1 folder"))
    if left_ns.size == 0:
        raise InputError("empty sequence: no images", path=mav0 / "cam0" / "data.csv")
    n = left_ns.size if max_frames is None else min(left_ns.size, max_frames)
    left_ns, lefts = left_ns[:n], lefts[:n]
    order = np.argsort(right_ns, kind="stable")
    if right_ns.size:
        nearest, diff = nearest_indices(right_ns[order].astype(np.float64), left_ns.astype(np.float64))
    else:
        nearest, diff = np.zeros(n, dtype=np.intp), np.full(n, np.inf)
    unmatched = np.flatnonzero(diff > STEREO_TOLERANCE_NS)
    if unmatched.size:
        k = int(unmatched[0])
        raise InputError(f"missing right image for left image {lefts[k]} (no cam1 row at t={left_ns[k]} ns)",
                         path=mav0 / "cam1" / "data.csv")
    paired = [rights[int(order[j])] for j in nearest]
    for left, right in zip(lefts, paired):
        if not left.is_file():
            raise InputError("left image listed in cam0/data.csv not found", path=left)
        if not right.is_file():
            raise InputError(f"missing right image for left image {left}", path=right)
    return left_ns, lefts, paired


def _find_ground_truth(root: Path, mav0: Path) -> Path | None:
    inside = mav0 / "state_groundtruth_estimate0" / "data.csv"
    if inside.is_file():
        return inside
    for folder in (root, mav0):
        for pattern in ("*groundtruth*.csv", "*groundtruth*.txt", "*ground_truth*.csv", "*ground_truth*.txt"):
            found = sorted(folder.glob(pattern))
            if found:
                return found[0]
    return None


def _gt_sensor_T_BS(gt_path: Path, mav0: Path) -> FloatArray:
    """T_BS of the ground-truth sensor: from its sensor.yaml for the in-folder ground truth, else identity."""
    yaml_path = mav0 / "state_groundtruth_estimate0" / "sensor.yaml"
    if gt_path.parent == yaml_path.parent and yaml_path.is_file():
        return _rigid_T_BS(_yaml_numbers(_load_yaml(yaml_path), "T_BS", 16, yaml_path), yaml_path)
    return np.eye(4)


def read_euroc(path: Path, max_frames: int | None = None, ground_truth: Path | None = None,
               alpha: float = 0.0, imu_options: ImuReadOptions | None = None,
               imu: Path | None = None) -> Sequence:
    """Open an EuRoC/ASL sequence (its root or its ``mav0`` folder) as rectified stereo.

    Args:
        path: the sequence root (holding ``mav0/``) or ``mav0`` itself.
        max_frames: keep only the first frames.
        ground_truth: an ASL csv or TUM file of body poses, instead of the one found in the folder.
        alpha: rectification free scaling (0: valid pixels only), see :func:`stereo_rectification`.
        imu_options: read ``mav0/imu0`` with these options (:mod:`gtvo.datasets.imu_files`; its
            ``T_cam_imu`` in the rectified left camera); None: no IMU.
        imu: an IMU CSV instead of ``mav0/imu0/data.csv`` (its ``sensor.yaml`` beside it).
    """
    require_dir(path, "EuRoC sequence folder")
    mav0 = find_mav0(path)
    if mav0 is None:
        raise InputError("no mav0/cam0 and mav0/cam1 folders", path=path)
    raw0, T_B_cam0 = read_sensor_yaml(mav0 / "cam0" / "sensor.yaml")
    raw1, T_B_cam1 = read_sensor_yaml(mav0 / "cam1" / "sensor.yaml")
    if raw0.size != raw1.size:
        raise InputError(f"cam0 is {raw0.width}x{raw0.height} but cam1 is {raw1.width}x{raw1.height} "
                         "(mismatched size)", path=mav0 / "cam1" / "sensor.yaml")
    left_ns, lefts, rights = _pair_stereo(mav0, max_frames)
    if image_size(lefts[0]) != raw0.size:  # (before the rectification tables of that size are made)
        width, height = image_size(lefts[0])
        raise InputError(f"resolution is {raw0.width}x{raw0.height} but the images are {width}x{height} "
                         f"({lefts[0].name})", path=mav0 / "cam0" / "sensor.yaml")
    T_cam1_cam0 = np.linalg.inv(T_B_cam1) @ T_B_cam0
    try:
        rect = stereo_rectification(raw0, raw1, T_cam1_cam0, alpha=alpha)
    except InputError as exc:
        raise InputError(str(exc), path=mav0) from None
    times = left_ns * 1e-9

    gt_path = ground_truth if ground_truth is not None else _find_ground_truth(path, mav0)
    gt_poses = None
    if gt_path is not None:
        gt_times, T_W_S = read_trajectory(gt_path)
        T_W_B = T_W_S @ np.linalg.inv(_gt_sensor_T_BS(gt_path, mav0))
        gt_poses = rect.rect_pose_from_cam0(interpolate_poses(gt_times, T_W_B, times, GT_TOLERANCE_S,
                                                              GT_MAX_GAP_S) @ T_B_cam0)
        require_overlap(gt_poses, gt_path, times, gt_times)

    shape = (raw0.height, raw0.width)
    root = path if mav0 != path else path.parent
    return Sequence(
        name=root.resolve().name, kind="stereo", camera=rect.camera, timestamps=times,
        load_left=RectifiedLoader(lefts, shape, "left", rect), load_right=RectifiedLoader(rights, shape, "right", rect),
        gt_poses=gt_poses, source=path, frame_names=[str(p) for p in lefts],
        imu=None if imu_options is None else read_imu_folder(mav0.parent, imu_options, T_B_cam0 @ rect.T_cam0_rect,
                                                                imu))
