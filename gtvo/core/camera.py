"""Pinhole and rectified-stereo cameras, vectorised over N points.

Conventions (docs/conventions.md): camera frame x right, y down, z forward; pixel (0, 0) is
the *centre* of the top-left pixel (OpenCV's convention), so a pixel's centre has integer
coordinates. Points are rows: ``points`` has shape (N, 3), pixels ``uv`` shape (N, 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.errors import InputError

FloatArray = NDArray[np.float64]

#: Points closer to the image plane than this (metres) count as behind the camera.
MIN_DEPTH = 1e-6


def _check_finite_positive(name: str, value: float) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise InputError(f"camera {name} must be a finite positive number, got {value!r}")
    return value


#: The fields of view (degrees, along one image axis) a pinhole camera may have: a focal length
#: outside them is a value in the wrong unit (metres, a normalised focal length), a typo or an
#: overflow, and no image can be tracked with it (the tracker's normal equations overflow or vanish).
FIELD_OF_VIEW_DEG: tuple[float, float] = (0.1, 179.0)


def _check_field_of_view(name: str, focal: float, size: int, axis: str) -> None:
    """Raise a one-line :class:`InputError` when the focal length ``focal`` (px) over ``size`` px
    gives a field of view outside :data:`FIELD_OF_VIEW_DEG`."""
    fov = float(np.degrees(2.0 * np.arctan2(size / 2.0, focal)))
    low, high = FIELD_OF_VIEW_DEG
    if not low <= fov <= high:
        raise InputError(f"camera {name} = {focal:g} px is implausible for an image {size} px {axis}: a field of "
                         f"view of {fov:.3g} degrees (a pinhole camera's lies between {low:g} and {high:g})")


@dataclass(frozen=True)
class PinholeCamera:
    """An undistorted pinhole camera ``u = fx * x / z + cx``, ``v = fy * y / z + cy``.

    Args:
        fx, fy: focal lengths in pixels.
        cx, cy: principal point in pixels (pixel centres are integers).
        width, height: image size in pixels.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        _check_finite_positive("fx", self.fx)
        _check_finite_positive("fy", self.fy)
        for name in ("cx", "cy"):
            if not np.isfinite(float(getattr(self, name))):
                raise InputError(f"camera {name} must be finite, got {getattr(self, name)!r}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise InputError(f"camera image size must be positive, got {self.width}x{self.height}")
        for name, size, axis in (("fx", self.width, "wide"), ("fy", self.height, "high")):
            _check_field_of_view(name, float(getattr(self, name)), int(size), axis)
        # A principal point off the image is a calibration for another resolution, swapped
        # values, or a misread file; every real camera's lies inside (KITTI's near the centre).
        # Half a pixel of slack past the far edge: a pyramid level (:meth:`scaled`) rounds its
        # size down but not ``cx``, which can then sit up to 1 px past its last pixel centre.
        if not (-0.5 <= self.cx <= self.width + 0.5 and -0.5 <= self.cy <= self.height + 0.5):
            raise InputError(f"camera principal point (cx, cy) = ({self.cx:g}, {self.cy:g}) lies outside the "
                             f"{self.width}x{self.height} image")

    @classmethod
    def from_matrix(cls, K: ArrayLike, width: int, height: int) -> "PinholeCamera":
        """Build from a 3x3 intrinsic matrix (skew must be zero)."""
        K = np.asarray(K, dtype=float)
        if K.shape != (3, 3):
            raise InputError(f"intrinsic matrix must be 3x3, got shape {K.shape}")
        if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]):
            raise InputError(f"intrinsic matrix has non-zero skew {K[0, 1]!r}; not supported")
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height))

    @property
    def K(self) -> FloatArray:
        """The 3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def K_inv(self) -> FloatArray:
        """The inverse of :attr:`K`."""
        return np.array([[1.0 / self.fx, 0.0, -self.cx / self.fx],
                         [0.0, 1.0 / self.fy, -self.cy / self.fy],
                         [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape as numpy has it: (height, width)."""
        return (int(self.height), int(self.width))

    def project(self, points: ArrayLike) -> tuple[FloatArray, NDArray[np.bool_]]:
        """Project camera-frame points (N, 3) to pixels (N, 2).

        Returns ``(uv, in_front)``; ``in_front`` is False where z <= MIN_DEPTH, and there
        ``uv`` is NaN-free but meaningless (z is clamped), so callers mask by it.
        """
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        z = p[:, 2]
        in_front = z > MIN_DEPTH
        zs = np.where(in_front, z, 1.0)
        uv = np.empty((p.shape[0], 2))
        uv[:, 0] = self.fx * p[:, 0] / zs + self.cx
        uv[:, 1] = self.fy * p[:, 1] / zs + self.cy
        return uv, in_front

    def bearing(self, uv: ArrayLike) -> FloatArray:
        """Normalised image coordinates ``(x/z, y/z, 1)`` of pixels (N, 2), shape (N, 3)."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        out = np.ones((uv.shape[0], 3))
        out[:, 0] = (uv[:, 0] - self.cx) / self.fx
        out[:, 1] = (uv[:, 1] - self.cy) / self.fy
        return out

    def backproject(self, uv: ArrayLike, depth: ArrayLike) -> FloatArray:
        """Back-project pixels (N, 2) with depths z (N,) to camera-frame points (N, 3)."""
        depth = np.asarray(depth, dtype=float).reshape(-1)
        return self.bearing(uv) * depth[:, None]

    def backproject_inverse_depth(self, uv: ArrayLike, inverse_depth: ArrayLike) -> FloatArray:
        """Back-project pixels with inverse depths ``d = 1/z`` (N,) to points (N, 3)."""
        d = np.asarray(inverse_depth, dtype=float).reshape(-1)
        return self.bearing(uv) / d[:, None]

    def contains(self, uv: ArrayLike, border: float = 0.0) -> NDArray[np.bool_]:
        """True where pixels lie at least ``border`` pixels inside the image (centres convention)."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        return ((uv[:, 0] >= border) & (uv[:, 0] <= self.width - 1 - border)
                & (uv[:, 1] >= border) & (uv[:, 1] <= self.height - 1 - border))

    def scaled(self, level: int) -> "PinholeCamera":
        """The camera of pyramid level ``level`` (each level halves the image by 2x2 averaging).

        With pixel centres at integers, a pixel ``u`` of level 0 is ``(u + 0.5) / 2 - 0.5`` on
        level 1, so ``cx`` maps the same way and ``fx`` halves.
        """
        if level < 0:
            raise InputError(f"pyramid level must be >= 0, got {level}")
        s = 2.0 ** (-level)
        return PinholeCamera(self.fx * s, self.fy * s, (self.cx + 0.5) * s - 0.5, (self.cy + 0.5) * s - 0.5,
                             int(self.width) >> level, int(self.height) >> level)


@dataclass(frozen=True)
class StereoCamera:
    """A rectified stereo pair: two identical pinholes, the right one at ``+baseline`` along x.

    A point at depth z in the left camera has disparity ``u_left - u_right = fx * baseline / z``.
    ``T_right_left`` maps left-camera coordinates to right-camera coordinates: ``x_r = x_l - b``.
    """

    left: PinholeCamera
    baseline: float

    def __post_init__(self) -> None:
        _check_finite_positive("baseline", self.baseline)

    @property
    def right(self) -> PinholeCamera:
        """The right camera's intrinsics (identical to the left after rectification)."""
        return self.left

    @property
    def T_right_left(self) -> FloatArray:
        """4x4 transform from left-camera to right-camera coordinates."""
        T = np.eye(4)
        T[0, 3] = -self.baseline
        return T

    def inverse_depth_from_disparity(self, disparity: ArrayLike) -> FloatArray:
        """Inverse depth ``d = disparity / (fx * b)``."""
        return np.asarray(disparity, dtype=float) / (self.left.fx * self.baseline)

    def project_right(self, points_left: ArrayLike) -> tuple[FloatArray, NDArray[np.bool_]]:
        """Project left-camera points (N, 3) into the right image."""
        p = np.asarray(points_left, dtype=float).reshape(-1, 3).copy()
        p[:, 0] -= self.baseline
        return self.left.project(p)

    def scaled(self, level: int) -> "StereoCamera":
        """The stereo camera of pyramid level ``level``."""
        return StereoCamera(self.left.scaled(level), self.baseline)
