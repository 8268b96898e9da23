"""Calibration of a ROS bag's cameras: from ``sensor_msgs/CameraInfo`` messages or a ``--calib``
file (KITTI ``calib.txt``, EuRoC ``sensor.yaml``, or a small YAML of two ROS camera_info blocks).

Every source becomes :class:`CameraModel` (the CameraInfo fields ``K, D, R, P``) and then a
:class:`BagCalibration`: the rectified camera, the per-image warps (None when the images are
already rectified) and ``T_raw_rect``, the pose of the rectified left camera in the raw left
camera's frame (a pure rotation ``[R^T | 0]``; the identity for rectified images).

* Rectified images (the topic name contains ``rect``, or ``D`` is zero and ``R`` the identity, or
  a KITTI ``calib.txt``): ``K = P_left[:, :3]`` and the baseline from ``P_right``, exactly as the
  KITTI reader (:func:`gtvo.datasets.kitti.rectified_from_projections`).
* Raw images: each image is warped with ``cv2.initUndistortRectifyMap(K, D, R, P)`` (the
  CameraInfo's own rectification, as ROS's ``image_proc`` does) and the rectified camera is the
  one of the ``P`` matrices. An EuRoC ``sensor.yaml`` has no ``R, P``: the pair is rectified with
  ``cv2.stereoRectify`` as the EuRoC reader does (:func:`gtvo.datasets.rectify.stereo_rectification`).

Layouts and the YAML form: ``docs/datasets.md`` ("ROS bags").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.core.lie import rotation_block_error
from gtvo.datasets._common import FloatArray
from gtvo.errors import InputError

ImageWarp = Callable[[NDArray[np.float32]], NDArray[np.float32]]
#: OpenCV-compatible distortion models of ROS CameraInfo.
SUPPORTED_DISTORTION = ("plumb_bob", "rational_polynomial", "radial-tangential", "radtan", "")
#: The numbers of distortion coefficients OpenCV's undistortion takes (0: none).
OPENCV_DISTORTION_SIZES = (0, 4, 5, 8, 12, 14)


@dataclass(frozen=True)
class CameraModel:
    """One camera's calibration in ROS ``CameraInfo`` terms.

    Attributes:
        width, height: image size (0 when the source does not say; taken from the images).
        K: 3x3 raw intrinsics; D: distortion coefficients; R: 3x3 rectifying rotation
        (``x_rect = R x_raw``); P: 3x4 projection of the rectified camera.
        distortion_model: ROS name (``plumb_bob``, ...).
        source: what to name in errors (``bag.bag:/cam/left/camera_info``, a file).
    """

    width: int
    height: int
    K: FloatArray
    D: FloatArray
    R: FloatArray
    P: FloatArray
    distortion_model: str = "plumb_bob"
    source: str = ""

    @property
    def is_undistorted(self) -> bool:
        """True when ``D`` is zero, ``R`` the identity and ``K = P[:, :3]``: rectifying the raw
        image would leave it as it is."""
        return bool(np.all(self.D == 0) and np.allclose(self.R, np.eye(3), atol=1e-12)
                    and np.allclose(self.K, self.P[:, :3], rtol=1e-9, atol=1e-9))


@dataclass(frozen=True)
class BagCalibration:
    """The rectified camera of a bag and how to get its images.

    Attributes:
        camera: :class:`StereoCamera` (stereo) or :class:`PinholeCamera` (RGB-D).
        warp_left, warp_right: per-image rectification (None: images used as they are).
        T_raw_rect: 4x4 pose of the rectified left camera in the raw left camera's frame.
        source: where the calibration came from (for ``gtvo info`` and errors).
        size: ``(width, height)`` the calibration is for (0, 0 when it does not say).
    """

    camera: StereoCamera | PinholeCamera
    warp_left: ImageWarp | None = None
    warp_right: ImageWarp | None = None
    T_raw_rect: FloatArray = field(default_factory=lambda: np.eye(4))
    source: str = ""
    size: tuple[int, int] = (0, 0)


def camera_model_from_msg(msg: Any, source: str) -> CameraModel:
    """A :class:`CameraModel` from a deserialised ``sensor_msgs/CameraInfo`` (ROS1 or ROS2 field
    names), refusing the all-zero ``K``/``P`` an uncalibrated driver publishes."""
    K = _matrix(getattr(msg, "k", getattr(msg, "K", None)), (3, 3), "K", source)
    P = _matrix(getattr(msg, "p", getattr(msg, "P", None)), (3, 4), "P", source)
    R = _matrix(getattr(msg, "r", getattr(msg, "R", None)), (3, 3), "R", source)
    D = np.asarray(getattr(msg, "d", getattr(msg, "D", [])), dtype=np.float64).reshape(-1)
    roi = getattr(msg, "roi", None)
    binned = max(int(getattr(msg, "binning_x", 0)), int(getattr(msg, "binning_y", 0))) > 1
    cropped = roi is not None and int(roi.width) > 0 and (int(roi.width), int(roi.height)) != (msg.width, msg.height)
    if binned or cropped:
        raise InputError("CameraInfo with binning or a region of interest is not supported: pass --calib FILE",
                         path=source)
    return checked_model(CameraModel(int(msg.width), int(msg.height), K, D, R, P,
                                     str(msg.distortion_model), source))


def _matrix(values: Any, shape: tuple[int, int], name: str, source: str) -> FloatArray:
    arr = np.asarray(values if values is not None else [], dtype=np.float64).reshape(-1)
    if arr.size != shape[0] * shape[1]:
        raise InputError(f"{name} needs {shape[0] * shape[1]} numbers, got {arr.size}", path=source)
    return arr.reshape(shape)


def checked_model(model: CameraModel) -> CameraModel:
    """``model`` when usable, else a one-line InputError naming its source (zeros, NaN, model)."""
    for name in ("K", "D", "R", "P"):
        if not np.all(np.isfinite(getattr(model, name))):
            raise InputError(f"camera calibration {name} contains NaN or infinite values", path=model.source)
    if not np.any(model.P) or not model.P[0, 0] > 0 or not model.P[1, 1] > 0:
        raise InputError(f"camera calibration has a zero projection matrix P (fx={model.P[0, 0]:g}, "
                         f"fy={model.P[1, 1]:g}): an uncalibrated camera; pass --calib FILE", path=model.source)
    if not model.is_undistorted and not (model.K[0, 0] > 0 and model.K[1, 1] > 0):
        raise InputError(f"camera calibration has a zero intrinsic matrix K (fx={model.K[0, 0]:g}) for raw "
                         f"images: an uncalibrated camera; pass --calib FILE", path=model.source)
    if model.distortion_model not in SUPPORTED_DISTORTION and not model.is_undistorted:
        raise InputError(f"distortion model {model.distortion_model!r} is not supported (plumb_bob, "
                         f"rational_polynomial)", path=model.source)
    return model


def stereo_calibration(left: CameraModel, right: CameraModel, rectified: bool,
                       size: tuple[int, int]) -> BagCalibration:
    """The rectified stereo camera of two :class:`CameraModel` (``rectified``: the images already
    are; else they are warped with each camera's ``K, D, R, P``). ``size`` = images' (width, height)."""
    from gtvo.datasets.kitti import rectified_from_projections  # noqa: PLC0415

    _check_size(left, size)
    _check_size(right, size)
    K, baseline, _ = rectified_from_projections(left.P, right.P, ("left P", "right P"), left.source)
    try:
        camera = StereoCamera(PinholeCamera.from_matrix(K, size[0], size[1]), baseline)
    except InputError as exc:
        raise InputError(str(exc), path=left.source) from None
    if rectified or (left.is_undistorted and right.is_undistorted):
        return BagCalibration(camera, source=left.source, size=size)
    _check_warpable(left)
    _check_warpable(right)
    T_raw_rect = np.eye(4)
    T_raw_rect[:3, :3] = left.R.T
    return BagCalibration(camera, _warp(left, size), _warp(right, size), T_raw_rect, left.source, size)


def rgbd_calibration(colour: CameraModel, rectified: bool, size: tuple[int, int]) -> BagCalibration:
    """The pinhole camera of an RGB-D bag: ``P[:, :3]`` for rectified colour images, else ``K``
    (no undistortion: the depth image is registered to the raw colour image, as the TUM reader)."""
    _check_size(colour, size)
    K = colour.P[:, :3] if rectified else colour.K
    try:
        camera = PinholeCamera.from_matrix(K, size[0], size[1])
    except InputError as exc:
        raise InputError(str(exc), path=colour.source) from None
    return BagCalibration(camera, source=colour.source, size=size)


def _check_size(model: CameraModel, size: tuple[int, int]) -> None:
    if model.width and model.height and (model.width, model.height) != tuple(size):
        raise InputError(f"calibration is for {model.width}x{model.height} images, the bag's are "
                         f"{size[0]}x{size[1]}", path=model.source)


def _check_warpable(model: CameraModel) -> None:
    """A raw camera's ``D`` and ``R`` as OpenCV's rectification takes them: a number of
    coefficients it knows and a rotation, else a one-line InputError naming the source."""
    if model.D.size not in OPENCV_DISTORTION_SIZES:
        raise InputError(f"camera calibration D has {model.D.size} coefficients; raw images can be rectified "
                         f"with {', '.join(map(str, OPENCV_DISTORTION_SIZES[1:]))} (plumb_bob: 5, "
                         f"rational_polynomial: 8)", path=model.source)
    problem = rotation_block_error(model.R)
    if problem is not None:
        raise InputError(f"camera calibration R {problem}", path=model.source)


def _warp(model: CameraModel, size: tuple[int, int]) -> ImageWarp:
    maps = cv2.initUndistortRectifyMap(model.K, model.D, model.R, model.P, size, cv2.CV_32FC1)

    def warp(image: NDArray[np.float32]) -> NDArray[np.float32]:
        return cv2.remap(np.asarray(image, dtype=np.float32), maps[0], maps[1], interpolation=cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    return warp


# --------------------------------------------------------------------------------------------
# --calib FILE

def read_calib_file(path: Path, kind: str, size: tuple[int, int]) -> BagCalibration:
    """The calibration in ``path`` for a ``kind`` (``"stereo"``/``"rgbd"``) bag of ``size`` images:
    a KITTI ``calib.txt`` (P0, P1: rectified), an EuRoC ``sensor.yaml`` (cam0's; cam1's is read
    from ``../cam1/sensor.yaml``), or a YAML with ``left:`` (and ``right:``) ROS camera_info blocks."""
    from gtvo.datasets._common import require_file  # noqa: PLC0415

    require_file(path, "calibration file (--calib)")
    if path.suffix.lower() not in (".yaml", ".yml"):
        return _kitti_calib(path, kind, size)
    from gtvo.datasets.euroc import _load_yaml  # noqa: PLC0415

    data = _load_yaml(path)
    if "T_BS" in data:
        return _euroc_calib(path, kind, size)
    if "left" not in data:
        raise InputError("calibration yaml needs 'left:' (and 'right:') camera_info blocks, or is an EuRoC "
                         "sensor.yaml (T_BS)", path=path)
    left = _yaml_camera(data["left"], f"{path}: left")
    if kind == "rgbd":
        return rgbd_calibration(left, False, size)
    if "right" not in data:
        raise InputError("stereo calibration yaml needs a 'right:' camera_info block", path=path)
    return stereo_calibration(left, _yaml_camera(data["right"], f"{path}: right"), False, size)


def _kitti_calib(path: Path, kind: str, size: tuple[int, int]) -> BagCalibration:
    from gtvo.datasets.kitti import read_projections  # noqa: PLC0415

    PL, PR = read_projections(path, ("P0", "P1"))
    models = [CameraModel(0, 0, P[:, :3].copy(), np.zeros(5), np.eye(3), P, "plumb_bob", str(path)) for P in (PL, PR)]
    if kind == "rgbd":
        return rgbd_calibration(checked_model(models[0]), True, size)
    return stereo_calibration(checked_model(models[0]), checked_model(models[1]), True, size)


def _euroc_calib(path: Path, kind: str, size: tuple[int, int]) -> BagCalibration:
    from gtvo.datasets.euroc import read_sensor_yaml  # noqa: PLC0415
    from gtvo.datasets.rectify import stereo_rectification  # noqa: PLC0415

    if kind == "rgbd":
        raise InputError("an EuRoC sensor.yaml calibrates a stereo pair, not an RGB-D camera", path=path)
    raw0, T_B_cam0 = read_sensor_yaml(path)
    other = path.parent.parent / "cam1" / path.name
    raw1, T_B_cam1 = read_sensor_yaml(other)
    if (raw0.width, raw0.height) != tuple(size):
        raise InputError(f"calibration is for {raw0.width}x{raw0.height} images, the bag's are {size[0]}x{size[1]}",
                         path=path)
    try:
        rect = stereo_rectification(raw0, raw1, np.linalg.inv(T_B_cam1) @ T_B_cam0)
    except InputError as exc:
        raise InputError(str(exc), path=path) from None
    return BagCalibration(rect.camera, rect.rectify_left, rect.rectify_right, rect.T_cam0_rect, str(path), size)


def _yaml_camera(block: Any, source: str) -> CameraModel:
    """A ROS camera_info yaml block (``image_width``, ``image_height``, ``projection_matrix``;
    optional ``camera_matrix``, ``distortion_model``, ``distortion_coefficients``,
    ``rectification_matrix``), each matrix a list or a ``{rows, cols, data}`` mapping."""
    from gtvo.datasets.euroc import _yaml_numbers  # noqa: PLC0415

    if not isinstance(block, dict):
        raise InputError("camera block must be a mapping of camera_info fields", path=source)
    P = _yaml_numbers(block, "projection_matrix", 12, Path(source)).reshape(3, 4)
    K = _yaml_numbers(block, "camera_matrix", 9, Path(source)).reshape(3, 3) if "camera_matrix" in block \
        else P[:, :3].copy()
    R = _yaml_numbers(block, "rectification_matrix", 9, Path(source)).reshape(3, 3) \
        if "rectification_matrix" in block else np.eye(3)
    D = np.zeros(5)
    if "distortion_coefficients" in block:
        value = block["distortion_coefficients"]
        try:
            D = np.asarray(value.get("data") if isinstance(value, dict) else value, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise InputError(f"distortion_coefficients must be a list of numbers, got {value!r}", path=source) from None
    try:
        width, height = int(block["image_width"]), int(block["image_height"])
    except (KeyError, TypeError, ValueError):
        raise InputError("camera block needs integer image_width and image_height", path=source) from None
    return checked_model(CameraModel(width, height, K, D, R, P, str(block.get("distortion_model", "plumb_bob")),
                                     source))
