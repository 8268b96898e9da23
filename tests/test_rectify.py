"""Stereo rectification (gtvo.datasets.rectify): synthetic geometry and the real EuRoC pair."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gtvo.errors import InputError
from gtvo.datasets.rectify import RawCamera, stereo_rectification


def _pair(rotation_deg: float = 2.0, baseline: float = 0.12):
    K0 = np.array([[460.0, 0, 370], [0, 458, 250], [0, 0, 1]])
    K1 = np.array([[455.0, 0, 380], [0, 456, 255], [0, 0, 1]])
    cam0 = RawCamera(K0, np.array([-0.28, 0.07, 2e-4, 2e-5]), 752, 480)
    cam1 = RawCamera(K1, np.array([-0.27, 0.075, -1e-4, -3e-5]), 752, 480)
    T = np.eye(4)  # x_cam1 = T x_cam0: cam1 sits at +baseline along cam0's x
    T[:3, :3] = Rotation.from_rotvec(np.deg2rad(rotation_deg) * np.array([0.3, 0.8, 0.5]) / np.linalg.norm(
        [0.3, 0.8, 0.5])).as_matrix()
    T[:3, 3] = -T[:3, :3] @ np.array([baseline, 0.004, -0.003])
    return cam0, cam1, T


def _sample(map_xy, uv):
    """Bilinear lookup of a remap table at float pixels (N, 2)."""
    mx = cv2.remap(map_xy[0], uv[:, 0].astype(np.float32)[None], uv[:, 1].astype(np.float32)[None],
                   cv2.INTER_LINEAR)
    my = cv2.remap(map_xy[1], uv[:, 0].astype(np.float32)[None], uv[:, 1].astype(np.float32)[None],
                   cv2.INTER_LINEAR)
    return np.stack([mx[0], my[0]], axis=1)


def test_synthetic_points_share_rows_and_disparity_matches_depth():
    cam0, cam1, T = _pair()
    rect = stereo_rectification(cam0, cam1, T)
    b_true = np.linalg.norm(np.linalg.inv(T)[:3, 3])
    assert rect.camera.baseline == pytest.approx(b_true, rel=1e-9)
    for R in (rect.R0, rect.R1, rect.R_cam0_rect):
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    rng = np.random.default_rng(0)
    X0 = np.column_stack([rng.uniform(-1.5, 1.5, 200), rng.uniform(-1, 1, 200), rng.uniform(2, 8, 200)])
    X1 = X0 @ T[:3, :3].T + T[:3, 3]
    # rectified-left coordinates of the points, projected with the shared K
    Xr = X0 @ rect.R0.T
    cam = rect.camera.left
    uv_l, _ = cam.project(Xr)
    uv_r, _ = rect.camera.project_right(Xr)
    keep = cam.contains(uv_l, 20) & cam.contains(uv_r, 20)
    assert keep.sum() > 50
    # the remap tables send those rectified pixels to the raw (distorted) projections
    raw0, _ = cv2.projectPoints(X0[keep], np.zeros(3), np.zeros(3), cam0.K, cam0.distortion)
    raw1, _ = cv2.projectPoints(X1[keep], np.zeros(3), np.zeros(3), cam1.K, cam1.distortion)
    np.testing.assert_allclose(_sample(rect.maps0, uv_l[keep]), raw0[:, 0], atol=0.02)  # px, map interpolation
    np.testing.assert_allclose(_sample(rect.maps1, uv_r[keep]), raw1[:, 0], atol=0.02)
    # and the same point has the same row left and right
    np.testing.assert_allclose(uv_l[keep, 1], uv_r[keep, 1], atol=1e-9)


def test_rect_pose_from_cam0_keeps_world_points():
    cam0, cam1, T = _pair()
    rect = stereo_rectification(cam0, cam1, T)
    T_w_cam0 = np.eye(4)
    T_w_cam0[:3, :3] = Rotation.from_rotvec([0.1, -0.4, 0.2]).as_matrix()
    T_w_cam0[:3, 3] = [1.0, 2.0, 3.0]
    x_cam0 = np.array([0.3, -0.2, 4.0])
    x_rect = rect.R0 @ x_cam0
    T_w_rect = rect.rect_pose_from_cam0(T_w_cam0)
    np.testing.assert_allclose(T_w_rect[:3, :3] @ x_rect + T_w_rect[:3, 3],
                               T_w_cam0[:3, :3] @ x_cam0 + T_w_cam0[:3, 3], atol=1e-12)


def test_bad_pairs_raise_input_error():
    cam0, cam1, T = _pair()
    swapped = np.linalg.inv(T)
    with pytest.raises(InputError, match="swapped"):
        stereo_rectification(cam1, cam0, swapped)
    vertical = np.eye(4)
    vertical[:3, 3] = [0.0, -0.12, 0.0]
    with pytest.raises(InputError, match="vertical"):
        stereo_rectification(cam0, cam1, vertical)
    with pytest.raises(InputError, match="different image sizes"):
        stereo_rectification(cam0, RawCamera(cam1.K, cam1.distortion, 640, 480), T)
    bad = T.copy()
    bad[0, 3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        stereo_rectification(cam0, cam1, bad)


def _orb_row_offsets(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """|dy| of cross-checked ORB matches with a plausible disparity (0..150 px, |dy| < 3 px)."""
    orb = cv2.ORB_create(2000)
    k1, d1 = orb.detectAndCompute(np.clip(left, 0, 255).astype(np.uint8), None)
    k2, d2 = orb.detectAndCompute(np.clip(right, 0, 255).astype(np.uint8), None)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d1, d2)
    p1 = np.array([k1[m.queryIdx].pt for m in matches])
    p2 = np.array([k2[m.trainIdx].pt for m in matches])
    d = p1 - p2
    ok = (np.abs(d[:, 1]) < 3) & (d[:, 0] > -1) & (d[:, 0] < 150)
    return np.abs(d[ok, 1])


@pytest.mark.realdata
def test_euroc_rectified_rows_agree(shared_data):
    from gtvo.datasets import open_sequence
    from gtvo.datasets._common import read_image

    seq = open_sequence(shared_data / "euroc_v101_static_stereo", max_frames=1)
    assert seq.camera.baseline == pytest.approx(0.11008, abs=2e-4)
    rect_dy = _orb_row_offsets(seq.left(0), seq.right(0))
    raw_dy = _orb_row_offsets(read_image(seq.load_left.paths[0]), read_image(seq.load_right.paths[0]))
    assert rect_dy.size > 200, rect_dy.size
    assert rect_dy.mean() < 0.5
    # the raw pair is not row-aligned: far fewer matches pass the same |dy| < 3 px gate
    assert raw_dy.size < rect_dy.size / 4
