"""ORB features of a keyframe and the 3-D points behind them (stereo or depth image).

Everything here is pure math on arrays (no file I/O). Pixel coordinates follow
docs/conventions.md: ``(u, v)`` = (column, row), the centre of the top-left pixel is (0, 0),
which is also how OpenCV reports keypoints.

Stereo depth at the keypoints (:func:`stereo_points`) follows ORB-SLAM2's
``Frame::ComputeStereoMatches``: ORB keypoints of the right image are matched to the left ones
along the same row (rectified pair), the match is refined to sub-pixel by a sum-of-absolute-
differences (SAD) search along the row and a parabola through the three best costs, and matches
with an outlying SAD are dropped. The disparity ``d`` gives the depth ``z = fx * b / d``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.errors import InputError
from gtvo.core.image import to_uint8
from gtvo.config.sections.loops import OrbConfig

FloatArray = NDArray[np.float64]
#: Bits in an ORB descriptor (32 bytes).
ORB_BITS = 256


@dataclass(frozen=True)
class OrbFeatures:
    """ORB keypoints of one image.

    Attributes:
        uv: (N, 2) pixel positions (column, row), pixel centres at integers.
        octave: (N,) ORB pyramid octave of each keypoint.
        descriptors: (N, 32) uint8 binary descriptors.
    """

    uv: FloatArray
    octave: NDArray[np.int64]
    descriptors: NDArray[np.uint8]

    def __len__(self) -> int:
        return int(self.uv.shape[0])


@dataclass(frozen=True)
class KeypointPoints:
    """3-D points behind some keypoints of a keyframe, in that keyframe's camera frame.

    Attributes:
        valid: (N,) True where the keypoint has a depth.
        points: (N, 3) camera-frame points (zeros where not valid).
        covariances: (N, 3, 3) point covariances in m^2 (identity where not valid).
    """

    valid: NDArray[np.bool_]
    points: FloatArray
    covariances: FloatArray


def extract_orb(image: NDArray, params: OrbConfig = OrbConfig(), detector: cv2.ORB | None = None) -> OrbFeatures:
    """ORB keypoints and descriptors of a gray image.

    Keypoints of octave ``o`` are moved by ``+0.5 (s - 1)`` pixels, ``s = scale_factor ** o``, to
    the pixel-centre convention (OpenCV scales level coordinates by ``s`` without that offset).
    """
    img = to_uint8(image)
    orb = detector if detector is not None else params.create()
    keypoints, descriptors = orb.detectAndCompute(img, None)
    if descriptors is None or len(keypoints) == 0:
        return OrbFeatures(np.zeros((0, 2)), np.zeros(0, dtype=np.int64), np.zeros((0, 32), dtype=np.uint8))
    uv = np.array([kp.pt for kp in keypoints], dtype=np.float64)
    octave = np.array([kp.octave & 0xFF for kp in keypoints], dtype=np.int64)
    # OpenCV reports pt = x_level * s, but its pyramid (cv2.resize) maps a level pixel centre
    # x_level to (x_level + 0.5) * s - 0.5 at full resolution.
    uv += 0.5 * (params.scale_factor ** octave[:, None] - 1.0)
    return OrbFeatures(uv, octave, np.ascontiguousarray(descriptors, dtype=np.uint8))


def signed_bits(descriptors: NDArray[np.uint8]) -> NDArray[np.float32]:
    """Descriptors (N, 32) uint8 as (N, 256) float32 of +-1, so that
    ``hamming(a, b) = (256 - a_s . b_s) / 2`` is one matrix product."""
    bits = np.unpackbits(np.asarray(descriptors, dtype=np.uint8), axis=1).astype(np.float32)
    return 2.0 * bits - 1.0


def hamming_distances(a: NDArray[np.uint8], b: NDArray[np.uint8]) -> NDArray[np.float32]:
    """All Hamming distances (N, M) between binary descriptors a (N, 32) and b (M, 32)."""
    return 0.5 * (ORB_BITS - signed_bits(a) @ signed_bits(b).T)


def _row_patches(image: NDArray[np.float32], rows: NDArray[np.int64], cols: NDArray[np.int64],
                 half: int) -> NDArray[np.float32]:
    """(M, 2h+1, 2h+1) patches centred at integer (cols, rows) of an edge-padded image."""
    pad = np.pad(image, half, mode="edge")
    offs = np.arange(-half, half + 1)
    r = np.clip(rows, 0, image.shape[0] - 1)[:, None, None] + offs[None, :, None] + half
    c = np.clip(cols, 0, image.shape[1] - 1)[:, None, None] + offs[None, None, :] + half
    return pad[r, c]


def stereo_points(left: OrbFeatures, left_image: NDArray, right_image: NDArray, stereo: StereoCamera,
                  params: OrbConfig = OrbConfig(), *, max_hamming: float = 75.0, row_tolerance_px: float = 2.0,
                  min_disparity_px: float = 0.5, sad_half_window: int = 5, sad_search_px: int = 5,
                  pixel_sigma_px: float = 1.0, disparity_sigma_px: float = 0.5,
                  detector: cv2.ORB | None = None) -> KeypointPoints:
    """Depth at the left keypoints of a rectified stereo pair, by ORB matching along rows.

    For left keypoint ``k`` (octave ``o``, scale ``s = scale_factor ** o``) the right candidates are
    the right ORB keypoints with ``|v_r - v_l| <= row_tolerance_px * s``, octave within one of
    ``o`` and disparity ``u_l - u_r`` in ``[min_disparity_px, fx * b / 0.1 m]``. The best one by
    Hamming distance (at most ``max_hamming``) that also prefers ``k`` back (mutual best) is
    refined by SAD along the row (patch ``2*sad_half_window+1`` square, shifts
    ``+-sad_search_px``, parabola sub-pixel step; a minimum on the border of the search is
    dropped) and matches whose SAD exceeds ``1.5 * 1.4 * median`` (ORB-SLAM2's rule) are dropped.

    The covariance of ``X = z K^-1 [u, v, 1]``, ``z = fx b / d``, comes from first-order
    propagation of ``sigma_u = sigma_v = pixel_sigma_px * s`` and ``sigma_d = disparity_sigma_px``.
    """
    if not isinstance(stereo, StereoCamera):
        raise InputError("a right image needs a StereoCamera")
    cam = stereo.left
    left_f = to_uint8(left_image, "left image").astype(np.float32)
    right_u8 = to_uint8(right_image, "right image")
    if right_u8.shape != (cam.height, cam.width):
        raise InputError(f"right image is {right_u8.shape[1]}x{right_u8.shape[0]}, "
                         f"the camera expects {cam.width}x{cam.height}")
    right = extract_orb(right_u8, params, detector)
    n = len(left)
    valid = np.zeros(n, dtype=bool)
    disparity = np.zeros(n)
    if n == 0 or len(right) == 0:
        return _points_from_disparity(cam, stereo.baseline, left, valid, disparity, params, pixel_sigma_px,
                                      disparity_sigma_px)
    scale_l = params.scale_factor ** left.octave
    max_disp = cam.fx * stereo.baseline / 0.1
    dist = hamming_distances(left.descriptors, right.descriptors)
    du = left.uv[:, 0:1] - right.uv[None, :, 0]
    dv = np.abs(left.uv[:, 1:2] - right.uv[None, :, 1])
    allowed = ((dv <= row_tolerance_px * scale_l[:, None]) & (du >= min_disparity_px) & (du <= max_disp)
               & (np.abs(left.octave[:, None] - right.octave[None, :]) <= 1))
    dist = np.where(allowed, dist, np.inf)
    best_r = np.argmin(dist, axis=1)
    best_d = dist[np.arange(n), best_r]
    best_l_of_r = np.argmin(dist, axis=0)
    ok = (best_d <= max_hamming) & (best_l_of_r[best_r] == np.arange(n))
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return _points_from_disparity(cam, stereo.baseline, left, valid, disparity, params, pixel_sigma_px,
                                      disparity_sigma_px)
    # Sub-pixel refinement by SAD along the row at full resolution (brightness offset removed
    # by subtracting each patch's centre pixel, as ORB-SLAM2 does).
    right_f = right_u8.astype(np.float32)
    h = int(sad_half_window)
    ul = np.rint(left.uv[idx, 0]).astype(np.int64)
    vl = np.rint(left.uv[idx, 1]).astype(np.int64)
    ur0 = np.rint(right.uv[best_r[idx], 0]).astype(np.int64)
    lp = _row_patches(left_f, vl, ul, h)
    lp = lp - lp[:, h:h + 1, h:h + 1]
    shifts = np.arange(-sad_search_px, sad_search_px + 1)
    sad = np.empty((idx.size, shifts.size), dtype=np.float32)
    for k, s in enumerate(shifts):  # loop over the few shifts, vectorised over keypoints
        rp = _row_patches(right_f, vl, ur0 + s, h)
        rp = rp - rp[:, h:h + 1, h:h + 1]
        sad[:, k] = np.abs(lp - rp).sum(axis=(1, 2))
    kbest = np.argmin(sad, axis=1)
    interior = (kbest > 0) & (kbest < shifts.size - 1)
    kb = np.clip(kbest, 1, shifts.size - 2)
    rows = np.arange(idx.size)
    s_m, s_0, s_p = sad[rows, kb - 1], sad[rows, kb], sad[rows, kb + 1]
    denom = 2.0 * (s_m + s_p - 2.0 * s_0)
    delta = np.where(denom > 0, (s_m - s_p) / np.where(denom > 0, denom, 1.0), 0.0)
    interior &= np.abs(delta) < 1.0
    ur = ur0 + shifts[kb] + delta
    d = ul - ur  # disparity of the patch centred on the rounded left keypoint
    best_sad = sad[rows, kbest]
    keep = interior & (d >= min_disparity_px) & (d <= max_disp)
    if np.any(keep):
        keep &= best_sad <= 1.5 * 1.4 * np.median(best_sad[keep])
    valid[idx[keep]] = True
    disparity[idx[keep]] = d[keep]
    return _points_from_disparity(cam, stereo.baseline, left, valid, disparity, params, pixel_sigma_px,
                                  disparity_sigma_px)


def _points_from_disparity(cam: PinholeCamera, baseline: float, feats: OrbFeatures, valid: NDArray[np.bool_],
                           disparity: FloatArray, params: OrbConfig, pixel_sigma_px: float,
                           disparity_sigma_px: float) -> KeypointPoints:
    n = len(feats)
    d = np.where(valid, disparity, 1.0)
    z = cam.fx * baseline / d
    points = cam.backproject(feats.uv, z) if n else np.zeros((0, 3))
    # d X / d (u, v, disparity): X = (u-cx) z/fx, Y = (v-cy) z/fy, Z = fx b / d; dz/dd = -z/d.
    J = np.zeros((n, 3, 3))
    J[:, 0, 0] = z / cam.fx
    J[:, 1, 1] = z / cam.fy
    J[:, :, 2] = -points / d[:, None]
    s = pixel_sigma_px * params.scale_factor ** feats.octave
    var = np.stack([s**2, s**2, np.full(n, disparity_sigma_px**2)], axis=1)
    cov = np.einsum("nij,nj,nkj->nik", J, var, J)
    points = np.where(valid[:, None], points, 0.0)
    cov = np.where(valid[:, None, None], cov, np.eye(3)[None])
    return KeypointPoints(valid, points, cov)


def depth_image_points(feats: OrbFeatures, depth: NDArray, camera: PinholeCamera, params: OrbConfig = OrbConfig(),
                       *, pixel_sigma_px: float = 1.0, depth_noise_per_m: float = 0.003) -> KeypointPoints:
    """3-D points at keypoints from a metric depth image (metres, 0 = unknown; e.g. RGB-D or a
    depth map the VO rendered from its own points), read at the nearest pixel.

    Depth noise ``sigma_z = depth_noise_per_m * z^2`` (a structured-light model); the point
    covariance propagates ``sigma_u = sigma_v = pixel_sigma_px * scale_factor ** octave`` and
    ``sigma_z`` through ``X = z K^-1 [u, v, 1]``.
    """
    dep = np.asarray(depth)
    if dep.shape != (camera.height, camera.width):
        raise InputError(f"depth image is {dep.shape[1] if dep.ndim > 1 else '?'}x{dep.shape[0]}, "
                         f"the camera expects {camera.width}x{camera.height}")
    dep = dep.astype(np.float64, copy=False)
    n = len(feats)
    col = np.clip(np.rint(feats.uv[:, 0]).astype(np.int64), 0, camera.width - 1)
    row = np.clip(np.rint(feats.uv[:, 1]).astype(np.int64), 0, camera.height - 1)
    z = dep[row, col] if n else np.zeros(0)
    valid = np.isfinite(z) & (z > 0)
    z = np.where(valid, z, 1.0)
    points = camera.backproject(feats.uv, z) if n else np.zeros((0, 3))
    J = np.zeros((n, 3, 3))
    J[:, 0, 0] = z / camera.fx
    J[:, 1, 1] = z / camera.fy
    J[:, :, 2] = points / z[:, None]
    s = pixel_sigma_px * params.scale_factor ** feats.octave
    var = np.stack([s**2, s**2, (depth_noise_per_m * z**2) ** 2], axis=1)
    cov = np.einsum("nij,nj,nkj->nik", J, var, J)
    points = np.where(valid[:, None], points, 0.0)
    cov = np.where(valid[:, None, None], cov, np.eye(3)[None])
    return KeypointPoints(valid, points, cov)
