"""Stereo rectification of a calibrated, distorted camera pair (OpenCV).

Given the intrinsics ``K0, K1``, radial-tangential distortions ``D0, D1`` and the extrinsics
``T_cam1_cam0`` (``x_cam1 = T_cam1_cam0 * x_cam0``), :func:`stereo_rectification` computes
rotations ``R0, R1`` (``x_rect0 = R0 x_cam0``, ``x_rect1 = R1 x_cam1``) that make both image
planes coplanar with rows aligned, and one shared pinhole ``K`` with zero distortion
(``cv2.stereoRectify`` with ``CALIB_ZERO_DISPARITY``). The rectified right camera sits at
``+baseline`` along the rectified left camera's x axis, as :class:`gtvo.core.camera.StereoCamera`
expects. The remap tables come from ``cv2.initUndistortRectifyMap`` and images are warped
with ``cv2.remap`` (bilinear; pixels that fall outside the raw image become 0).

The rectified left camera is rotated with respect to the raw cam0: a pose of raw cam0 becomes
a pose of the rectified camera as ``T_W_rect = T_W_cam0 * [R_cam0_rect | 0]`` with
``R_cam0_rect = R0^T`` (:meth:`StereoRectification.rect_pose_from_cam0`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.errors import InputError

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class RawCamera:
    """A raw (distorted, unrectified) pinhole camera with radial-tangential distortion.

    Attributes:
        K: 3x3 intrinsic matrix.
        distortion: OpenCV coefficients ``[k1, k2, p1, p2(, k3)]``.
        width, height: image size in pixels.
    """

    K: FloatArray
    distortion: FloatArray
    width: int
    height: int

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` as OpenCV wants it."""
        return (int(self.width), int(self.height))


@dataclass(frozen=True)
class StereoRectification:
    """The result of :func:`stereo_rectification`: the rectified camera and the remap tables.

    Attributes:
        camera: the rectified :class:`StereoCamera` (shared ``K``, baseline in metres).
        R0, R1: rectifying rotations, ``x_rect0 = R0 x_cam0`` and ``x_rect1 = R1 x_cam1``.
        maps0, maps1: ``(map_x, map_y)`` float32 tables of the left and right images.
    """

    camera: StereoCamera
    R0: FloatArray
    R1: FloatArray
    maps0: tuple[NDArray[np.float32], NDArray[np.float32]]
    maps1: tuple[NDArray[np.float32], NDArray[np.float32]]

    @property
    def R_cam0_rect(self) -> FloatArray:
        """Rotation taking rectified-left coordinates to raw cam0 coordinates (``R0^T``)."""
        return self.R0.T

    @property
    def T_cam0_rect(self) -> FloatArray:
        """4x4 pose of the rectified left camera in the raw cam0 frame (pure rotation)."""
        T = np.eye(4)
        T[:3, :3] = self.R_cam0_rect
        return T

    def rect_pose_from_cam0(self, T_world_cam0: ArrayLike) -> FloatArray:
        """``T_world_rect = T_world_cam0 * T_cam0_rect`` for poses (..., 4, 4) (NaN stays NaN)."""
        return np.asarray(T_world_cam0, dtype=np.float64) @ self.T_cam0_rect

    def rectify_left(self, image: NDArray) -> NDArray[np.float32]:
        """Warp a raw left image (float32 gray) into the rectified left image."""
        return _remap(image, self.maps0)

    def rectify_right(self, image: NDArray) -> NDArray[np.float32]:
        """Warp a raw right image (float32 gray) into the rectified right image."""
        return _remap(image, self.maps1)


def _remap(image: NDArray, maps: tuple[NDArray[np.float32], NDArray[np.float32]]) -> NDArray[np.float32]:
    img = np.asarray(image, dtype=np.float32)
    return cv2.remap(img, maps[0], maps[1], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=0)


def stereo_rectification(cam0: RawCamera, cam1: RawCamera, T_cam1_cam0: ArrayLike,
                         alpha: float = 0.0) -> StereoRectification:
    """Rectify a horizontal stereo pair whose right camera ``cam1`` lies at +x of ``cam0``.

    Args:
        cam0, cam1: raw left and right cameras (same image size).
        T_cam1_cam0: 4x4, maps cam0 coordinates into cam1 coordinates.
        alpha: OpenCV's free scaling: 0 keeps only valid pixels (no black borders), 1 keeps
            every raw pixel.

    Raises:
        InputError: different image sizes, non-finite calibration, a vertical or swapped pair.
    """
    T = np.asarray(T_cam1_cam0, dtype=np.float64)
    for name, value in (("K0", cam0.K), ("K1", cam1.K), ("D0", cam0.distortion), ("D1", cam1.distortion),
                        ("T_cam1_cam0", T)):
        if not np.all(np.isfinite(value)):
            raise InputError(f"stereo calibration {name} contains NaN or infinite values")
    if cam0.size != cam1.size:
        raise InputError(f"stereo cameras have different image sizes {cam0.size} and {cam1.size}")
    size = cam0.size
    R0, R1, P0, P1, _Q, _roi0, _roi1 = cv2.stereoRectify(
        cam0.K, cam0.distortion, cam1.K, cam1.distortion, size, T[:3, :3].copy(), T[:3, 3].reshape(3, 1).copy(),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha, newImageSize=size)
    if abs(P1[1, 3]) > abs(P1[0, 3]):
        raise InputError("stereo pair is vertical (cam1 above/below cam0); only horizontal pairs are supported")
    baseline = -float(P1[0, 3]) / float(P1[0, 0])
    if not baseline > 0:
        raise InputError(f"stereo pair is swapped: cam1 is to the left of cam0 (baseline {baseline:.4f} m)")
    left = PinholeCamera.from_matrix(P0[:3, :3], size[0], size[1])
    maps0 = cv2.initUndistortRectifyMap(cam0.K, cam0.distortion, R0, P0, size, cv2.CV_32FC1)
    maps1 = cv2.initUndistortRectifyMap(cam1.K, cam1.distortion, R1, P1, size, cv2.CV_32FC1)
    return StereoRectification(StereoCamera(left, baseline), np.asarray(R0), np.asarray(R1),
                               (maps0[0], maps0[1]), (maps1[0], maps1[1]))
