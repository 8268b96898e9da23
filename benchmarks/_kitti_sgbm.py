"""KITTI snippet loading and a stand-in keyframe (gradient points + StereoSGBM depths) for
benchmarks and the real-data tracking test. gtvo's own stereo depth (gtvo.frontend) replaces
this in the pipeline; this helper only needs OpenCV."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.core.image import image_gradients, to_float_gray

#: assumed SGBM disparity noise (px) for the stand-in inverse-depth variance
DISPARITY_SIGMA = 0.5


def load_kitti(folder: Path) -> tuple[StereoCamera, list[Path], list[Path], np.ndarray]:
    """Camera, left/right image paths and GT poses (N, 4, 4) of a KITTI_sequence_1-style folder."""
    P = np.loadtxt(folder / "calib.txt").reshape(2, 3, 4)
    left = sorted((folder / "image_l").glob("*.png"))
    right = sorted((folder / "image_r").glob("*.png"))
    img = cv2.imread(str(left[0]), cv2.IMREAD_GRAYSCALE)
    cam = PinholeCamera.from_matrix(P[0][:, :3], img.shape[1], img.shape[0])
    stereo = StereoCamera(cam, float(-P[1][0, 3] / P[1][0, 0]))
    rows = np.loadtxt(folder / "poses.txt").reshape(-1, 3, 4)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = rows
    return stereo, left, right, poses


def read_gray(path: Path) -> np.ndarray:
    return to_float_gray(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), str(path))


def sgbm_keyframe_points(left: np.ndarray, right: np.ndarray, stereo: StereoCamera, n_points: int,
                         border: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Up to ``n_points`` high-gradient pixels spread on a grid, with SGBM inverse depths.

    Returns (pixels (N, 2), inverse depths (N,), variances (N,)).
    """
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=128, blockSize=5, P1=8 * 25, P2=32 * 25,
                                 uniquenessRatio=10, speckleWindowSize=100, speckleRange=2, disp12MaxDiff=1)
    disp = sgbm.compute(left.astype(np.uint8), right.astype(np.uint8)).astype(np.float32) / 16.0
    gx, gy = image_gradients(left)
    g = np.hypot(gx, gy)
    ok = disp > 1.0
    ok[:border] = ok[-border:] = False
    ok[:, :border] = ok[:, -border:] = False
    h, w = left.shape
    g = np.where(ok, g, -1.0)
    cell = max(2, int(np.sqrt(h * w / (1.5 * n_points))))
    hh, ww = (h // cell) * cell, (w // cell) * cell
    blocks = g[:hh, :ww].reshape(hh // cell, cell, ww // cell, cell).transpose(0, 2, 1, 3).reshape(-1, cell * cell)
    arg = blocks.argmax(1)
    best = blocks[np.arange(len(arg)), arg]
    by, bx = np.divmod(np.arange(len(arg)), ww // cell)
    v = by * cell + arg // cell
    u = bx * cell + arg % cell
    keep = best > 5.0
    order = np.argsort(-best[keep])[:n_points]
    u, v = u[keep][order], v[keep][order]
    fb = stereo.left.fx * stereo.baseline
    d = disp[v, u] / fb
    V = np.full(d.shape, (DISPARITY_SIGMA / fb) ** 2)
    return np.c_[u, v].astype(float), d.astype(float), V
