"""The two visual-odometry peers a user would otherwise build from this stack (issue 4, item 5).

Benchmark material, not part of the gtvo package: ``benchmarks/kitti_vo.py`` runs them beside
gtvo on the same frames, and ``tests/test_peers_benchmark.py`` checks them on three KITTI frames.

* :class:`Open3DColorOdometryPeer` -- (a) OpenCV StereoSGBM depth (``numDisparities`` 128,
  ``blockSize`` 5, ``P1 = 8 * 5^2``, ``P2 = 32 * 5^2``, 3-way mode) and Open3D's
  ``compute_rgbd_odometry`` frame to frame with the colour (photometric) term, ``depth_max``
  40 m, and a constant-velocity initial guess. Open3D's default hybrid term is not used: it
  drifts by about 99 % on outdoor KITTI data.
* :class:`OrbPnPPeer` -- (b) ORB features matched frame to frame, the previous frame's keypoints
  lifted to 3-D with the same SGBM depth, and ``cv2.solvePnPRansac`` (then Levenberg-Marquardt on
  the inliers) for the current frame's pose.

Both take a :class:`gtvo.datasets.sequence.Frame` at a time (stereo: depth from SGBM; RGB-D: the sensor's
depth) and return ``T_world_cam`` of the left camera (docs/conventions.md), the first frame at
the identity. Relative motions: ``T_prev_cur`` is the current camera's pose in the previous
camera's frame, so ``T_world_cur = T_world_prev @ T_prev_cur``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from gtvo.core.optional import require_open3d
from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.errors import InputError
from gtvo.core.image import to_uint8
from gtvo.datasets.sequence import Frame
from gtvo.evaluation.trajectory import Trajectory

FloatArray = NDArray[np.float64]

#: StereoSGBM settings of the issue's peers.
SGBM_NUM_DISPARITIES = 128
SGBM_BLOCK_SIZE = 5
#: Depths beyond this (metres) are dropped by both peers (the issue's ``depth_max``).
DEPTH_MAX_M = 40.0
#: Open3D's correspondence gate ``|z_target - z_source'|`` for SGBM depth: about the depth error of a
#: 1/4 px disparity error at 20 m on KITTI (``z^2 * 0.25 / (fx * b)`` = 0.26 m). Open3D's default
#: (0.03 m, made for structured-light sensors) keeps only the nearest points on KITTI and drifts
#: 8 % (docs/benchmarks.md has the sweep).
STEREO_DEPTH_DIFF_MAX_M = 0.3
#: ... and for a sensor's depth (RGB-D): Open3D's default.
RGBD_DEPTH_DIFF_MAX_M = 0.03


def make_sgbm() -> cv2.StereoSGBM:
    """OpenCV's semi-global matcher with the issue's settings (3-way mode)."""
    b = SGBM_BLOCK_SIZE
    return cv2.StereoSGBM_create(minDisparity=0, numDisparities=SGBM_NUM_DISPARITIES, blockSize=b,
                                 P1=8 * b * b, P2=32 * b * b, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)


def sgbm_depth(matcher: cv2.StereoSGBM, left: NDArray, right: NDArray, camera: StereoCamera,
               depth_max: float = DEPTH_MAX_M) -> NDArray[np.float32]:
    """Metric depth of the left image from SGBM disparity: ``z = fx * b / disparity``.

    Pixels with no disparity (SGBM marks them below ``minDisparity``), a disparity <= 0, or a
    depth beyond ``depth_max`` get 0 (no measurement).
    """
    raw = matcher.compute(to_uint8(left), to_uint8(right))  # int16, disparity * 16
    disp = raw.astype(np.float32) / 16.0
    depth = np.zeros(disp.shape, dtype=np.float32)
    ok = disp > 0.0
    depth[ok] = np.float32(camera.left.fx * camera.baseline) / disp[ok]
    depth[depth > depth_max] = 0.0
    return depth


def frame_depth(frame: Frame, camera: StereoCamera | PinholeCamera, matcher: cv2.StereoSGBM | None,
                depth_max: float = DEPTH_MAX_M) -> NDArray[np.float32]:
    """Depth of ``frame``'s left image: SGBM for stereo frames, the sensor's for RGB-D frames."""
    if isinstance(camera, StereoCamera):
        if frame.right is None or matcher is None:
            raise InputError(f"frame {frame.index}: stereo peer needs a right image")
        return sgbm_depth(matcher, frame.left, frame.right, camera, depth_max)
    if frame.depth is None:
        raise InputError(f"frame {frame.index}: RGB-D peer needs a depth image")
    d = np.nan_to_num(np.asarray(frame.depth, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    d[(d < 0) | (d > depth_max)] = 0.0
    return d


def se3_inverse(T: FloatArray) -> FloatArray:
    """Inverse ``[R^T, -R^T t]`` of a 4x4 rigid transform."""
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


class Peer(Protocol):
    """A frame-to-frame odometry peer (what :func:`run_peer` drives)."""

    name: str
    failures: int

    def process(self, frame: Frame) -> FloatArray:
        """``T_world_cam`` of ``frame``."""
        ...

    def trajectory(self, name: str) -> Trajectory:
        """The estimated trajectory so far."""
        ...


@dataclass
class _FrameToFrame:
    """Bookkeeping shared by the peers: poses, the last relative motion, failures."""

    camera: StereoCamera | PinholeCamera
    poses: list[FloatArray] = field(default_factory=list)
    timestamps: list[float] = field(default_factory=list)
    failures: int = 0
    last_motion: FloatArray = field(default_factory=lambda: np.eye(4))  # T_prev_cur of the last step

    @property
    def pinhole(self) -> PinholeCamera:
        return self.camera.left if isinstance(self.camera, StereoCamera) else self.camera

    def _push(self, frame: Frame, T_prev_cur: FloatArray | None) -> FloatArray:
        if T_prev_cur is None:  # first frame
            T = np.eye(4)
        else:
            self.last_motion = T_prev_cur
            T = self.poses[-1] @ T_prev_cur
        self.poses.append(T)
        self.timestamps.append(float(frame.timestamp))
        return T

    def trajectory(self, name: str) -> Trajectory:
        """The estimated trajectory so far."""
        return Trajectory(np.array(self.timestamps), np.stack(self.poses), name=name)


class Open3DColorOdometryPeer(_FrameToFrame):
    """Peer (a): SGBM (or sensor) depth + Open3D RGB-D odometry with the colour term.

    Args:
        camera: stereo (depth from SGBM) or pinhole (RGB-D, the sensor's depth).
        depth_max: depth truncation in metres (``depth_trunc`` and ``OdometryOption.depth_max``).
        depth_diff_max: Open3D's correspondence gate ``|z_target - z_source'|`` in metres; None:
            :data:`STEREO_DEPTH_DIFF_MAX_M` for stereo, :data:`RGBD_DEPTH_DIFF_MAX_M` for RGB-D.

    The RGBD image is built from the left gray image as 8-bit with
    ``convert_rgb_to_intensity=True``, which makes Open3D store a float intensity in [0, 1] (what
    its odometry requires: one float channel), and the depth as float metres with
    ``depth_scale=1``. Open3D returns the transform that maps the *source* frame's points into the
    *target* frame; with source = current and target = previous frame that is ``T_prev_cur``.
    The initial guess is the last step's motion (constant velocity).
    """

    name = "SGBM + Open3D RGB-D odometry (colour term)"

    def __init__(self, camera: StereoCamera | PinholeCamera, depth_max: float = DEPTH_MAX_M,
                 depth_diff_max: float | None = None) -> None:
        super().__init__(camera)
        o3d = require_open3d()
        self._o3d = o3d
        self.depth_max = float(depth_max)
        self._matcher = make_sgbm() if isinstance(camera, StereoCamera) else None
        if depth_diff_max is None:
            depth_diff_max = STEREO_DEPTH_DIFF_MAX_M if self._matcher is not None else RGBD_DEPTH_DIFF_MAX_M
        self.depth_diff_max = float(depth_diff_max)
        pin = self.pinhole
        self._intrinsic = o3d.camera.PinholeCameraIntrinsic(pin.width, pin.height, pin.fx, pin.fy, pin.cx, pin.cy)
        self._option = o3d.pipelines.odometry.OdometryOption(depth_diff_max=self.depth_diff_max,
                                                             depth_min=0.0, depth_max=self.depth_max)
        self._jacobian = o3d.pipelines.odometry.RGBDOdometryJacobianFromColorTerm()
        self._prev = None

    def rgbd_image(self, frame: Frame):  # -> o3d.geometry.RGBDImage
        """The Open3D RGBD image of ``frame`` (intensity in [0, 1], depth in metres)."""
        o3d = self._o3d
        depth = frame_depth(frame, self.camera, self._matcher, self.depth_max)
        color = o3d.geometry.Image(np.ascontiguousarray(to_uint8(frame.left)))
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            color, o3d.geometry.Image(np.ascontiguousarray(depth)), depth_scale=1.0, depth_trunc=self.depth_max,
            convert_rgb_to_intensity=True)

    def process(self, frame: Frame) -> FloatArray:
        """``T_world_cam`` of ``frame``; a failed step keeps the constant-velocity guess."""
        rgbd = self.rgbd_image(frame)
        if self._prev is None:
            self._prev = rgbd
            return self._push(frame, None)
        # Open3D's odo_init maps source (current) points into the target (previous) frame: T_prev_cur.
        init = self.last_motion.copy()
        ok, T_prev_cur, _info = self._o3d.pipelines.odometry.compute_rgbd_odometry(
            rgbd, self._prev, self._intrinsic, init, self._jacobian, self._option)
        if not ok or not np.all(np.isfinite(T_prev_cur)):
            self.failures += 1
            T_prev_cur = init
        self._prev = rgbd
        return self._push(frame, np.asarray(T_prev_cur, dtype=np.float64))


class OrbPnPPeer(_FrameToFrame):
    """Peer (b): ORB features + SGBM (or sensor) depth + ``cv2.solvePnPRansac``, frame to frame.

    Each frame: ORB keypoints and descriptors of the left image and the depth map. The previous
    frame's keypoints with a depth in ``(0, depth_max]`` are lifted to 3-D in the previous camera
    frame; they are matched to the current keypoints (Hamming distance, Lowe's ratio test), and
    ``solvePnPRansac`` finds ``T_cur_prev`` (object = previous camera frame), refined by
    ``solvePnPRefineLM`` on the inliers. With fewer than ``min_inliers`` inliers the step counts
    as a failure and the constant-velocity motion is kept.

    Args:
        camera: stereo (depth from SGBM) or pinhole (RGB-D, the sensor's depth).
        n_features: ORB keypoints per image.
        ratio: Lowe's ratio test threshold.
        reprojection_error: RANSAC inlier threshold in pixels.
        min_inliers: fewest RANSAC inliers for a step to count as tracked.
    """

    name = "ORB + SGBM + solvePnPRansac"

    def __init__(self, camera: StereoCamera | PinholeCamera, n_features: int = 3000, ratio: float = 0.8,
                 reprojection_error: float = 1.5, min_inliers: int = 15, depth_max: float = DEPTH_MAX_M) -> None:
        super().__init__(camera)
        self._matcher = make_sgbm() if isinstance(camera, StereoCamera) else None
        self.n_features = int(n_features)
        self._orb = cv2.ORB_create(nfeatures=self.n_features)
        self._bf = cv2.BFMatcher(cv2.NORM_HAMMING)
        self.ratio = float(ratio)
        self.reprojection_error = float(reprojection_error)
        self.min_inliers = int(min_inliers)
        self.depth_max = float(depth_max)
        self._prev: tuple[NDArray, NDArray, NDArray] | None = None  # previous frame's (pixels, descriptors, 3-D points)
        self.inliers: list[int] = []

    def _features(self, frame: Frame) -> tuple[FloatArray, NDArray[np.uint8], FloatArray]:
        """Keypoint pixels (N, 2), descriptors (N, 32) and their 3-D points (N, 3) (NaN without depth)."""
        img = to_uint8(frame.left)
        kps, desc = self._orb.detectAndCompute(img, None)
        if desc is None or not kps:
            return np.zeros((0, 2)), np.zeros((0, 32), np.uint8), np.zeros((0, 3))
        uv = np.array([k.pt for k in kps], dtype=np.float64)
        depth = frame_depth(frame, self.camera, self._matcher, self.depth_max)
        iu = np.clip(np.rint(uv[:, 0]).astype(np.intp), 0, depth.shape[1] - 1)
        iv = np.clip(np.rint(uv[:, 1]).astype(np.intp), 0, depth.shape[0] - 1)
        z = depth[iv, iu].astype(np.float64)
        pin = self.pinhole
        X = np.column_stack([(uv[:, 0] - pin.cx) / pin.fx * z, (uv[:, 1] - pin.cy) / pin.fy * z, z])
        X[~(z > 0)] = np.nan
        return uv, desc, X

    def process(self, frame: Frame) -> FloatArray:
        """``T_world_cam`` of ``frame``; a failed step keeps the constant-velocity motion."""
        uv, desc, X = self._features(frame)
        prev = self._prev
        self._prev = (uv, desc, X)
        if prev is None:
            return self._push(frame, None)
        _, desc_prev, X_prev = prev
        T_prev_cur = self._estimate(desc_prev, X_prev, uv, desc)
        if T_prev_cur is None:
            self.failures += 1
            T_prev_cur = self.last_motion.copy()
        return self._push(frame, T_prev_cur)

    def _estimate(self, desc_prev: NDArray, X_prev: FloatArray, uv: FloatArray, desc: NDArray) -> FloatArray | None:
        has_depth = np.isfinite(X_prev[:, 2])
        if has_depth.sum() < self.min_inliers or len(desc) < 2:
            self.inliers.append(0)
            return None
        idx_prev = np.flatnonzero(has_depth)
        knn = self._bf.knnMatch(desc_prev[idx_prev], desc, k=2)
        pairs = [(m[0].queryIdx, m[0].trainIdx) for m in knn
                 if len(m) == 2 and m[0].distance < self.ratio * m[1].distance]
        if len(pairs) < self.min_inliers:
            self.inliers.append(0)
            return None
        q, t = np.array(pairs, dtype=np.intp).T
        obj = X_prev[idx_prev[q]].astype(np.float64)
        img = uv[t].astype(np.float64)
        K = self.pinhole.K
        ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, K, None, iterationsCount=200,
                                                 reprojectionError=self.reprojection_error, confidence=0.999,
                                                 flags=cv2.SOLVEPNP_EPNP)
        n_in = 0 if inl is None else len(inl)
        self.inliers.append(n_in)
        if not ok or n_in < self.min_inliers:
            return None
        inl = inl.reshape(-1)
        rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], K, None, rvec, tvec)
        T_cur_prev = np.eye(4)
        T_cur_prev[:3, :3] = cv2.Rodrigues(rvec)[0]
        T_cur_prev[:3, 3] = tvec.reshape(3)
        if not np.all(np.isfinite(T_cur_prev)):
            return None
        return se3_inverse(T_cur_prev)


@dataclass(frozen=True)
class PeerRun:
    """A peer's run over a sequence.

    Attributes:
        name: the peer's name.
        trajectory: ``T_world_cam`` of every processed frame.
        seconds: total wall time of ``process`` over all frames (image loading excluded).
        frame_seconds: (N,) wall time per frame.
        failures: steps where the peer's own estimate failed (the constant-velocity motion was kept).
    """

    name: str
    trajectory: Trajectory
    seconds: float
    frame_seconds: FloatArray
    failures: int


def run_peer(peer: Peer, frames: list[Frame], name: str | None = None) -> PeerRun:
    """Feed ``frames`` (already loaded, so reading is not timed) to ``peer`` and time each step."""
    if not frames:
        raise InputError("no frames to run the peer on")
    times = np.empty(len(frames))
    for k, frame in enumerate(frames):
        t0 = time.perf_counter()
        peer.process(frame)
        times[k] = time.perf_counter() - t0
    label = name or peer.name
    return PeerRun(label, peer.trajectory(label), float(times.sum()), times, peer.failures)

