"""A wide-basin pose guess from sparse optical flow and PnP, for when the motion model has none.

Direct tracking converges from a guess within a few pixels (on the coarsest pyramid level) of the
true motion. The motion model gives such a guess while the camera moves smoothly, but not on the
first frames of a run (no velocity yet), after a re-initialisation, or after an abrupt change of
speed (e.g. KITTI played at 5 Hz: 2.4 m between frames, 100 px of flow near the image border).
:func:`optical_flow_pose` gives the tracker a guess for those cases:

1. the keyframe's points (pixels with a stereo or sensor inverse depth) are followed into the
   frame by pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``, zero initial flow, so it does
   not need any motion prior), and followed back (the forward-backward check of Kalal,
   Mikolajczyk and Matas, 2010): a point that does not return within ``max_forward_backward_px`` is dropped;
2. ``cv2.solvePnPRansac`` (EPnP in RANSAC, then Levenberg-Marquardt on the inliers) finds the
   frame's pose from the points' 3-D positions in the keyframe and their tracked pixels.

The result only seeds the direct tracker, which refines it against every point; it is never
used as a pose by itself. Measured on KITTI_sequence_1 (300 points per keyframe, keyframes every
5 frames): 2.4 m steps give a guess within 8 cm and 0.26 deg, 4.8 m steps within 0.37 m and
0.5 deg; at 6 m it returns None for a third of the keyframes (docs/frontend.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.core.camera import PinholeCamera
from gtvo.config.sections.flow_fallback import FlowPoseConfig
from gtvo.errors import InputError
from gtvo.core.image import to_uint8
from gtvo.core.lie import invert_poses

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class FlowPose:
    """A pose guess from :func:`optical_flow_pose`.

    Attributes:
        T_keyframe_frame: (4, 4) the frame's pose in the keyframe's camera frame.
        n_tracked: points that passed the forward-backward check.
        n_inliers: PnP RANSAC inliers among them.
    """

    T_keyframe_frame: FloatArray
    n_tracked: int
    n_inliers: int


def optical_flow_pose(camera: PinholeCamera, keyframe_image: ArrayLike, pixels: ArrayLike,
                      inverse_depth: ArrayLike, frame_image: ArrayLike,
                      config: FlowPoseConfig | None = None) -> FlowPose | None:
    """The frame's pose relative to the keyframe from its points' optical flow (module doc).

    Args:
        camera: the (left) camera of both images.
        keyframe_image, frame_image: (H, W) gray images, grey levels (uint8 or float).
        pixels: (N, 2) the keyframe's point pixels ``(u, v)``.
        inverse_depth: (N,) their inverse depths in the keyframe (> 0).
        config: settings.

    Returns:
        The guess, or None when fewer than ``config.min_inliers`` points support one.
    """
    cfg = config or FlowPoseConfig()
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    d = np.asarray(inverse_depth, dtype=np.float64).reshape(-1)
    if d.shape[0] != px.shape[0]:
        raise InputError(f"optical_flow_pose: {px.shape[0]} pixels but {d.shape[0]} inverse depths")
    I0, I1 = to_uint8(keyframe_image, "keyframe image"), to_uint8(frame_image, "frame image")
    for name, img in (("keyframe", I0), ("frame", I1)):
        if img.shape[:2] != camera.shape:
            raise InputError(f"optical_flow_pose: {name} image is {img.shape[1]}x{img.shape[0]}, "
                             f"camera says {camera.width}x{camera.height}")
    ok = np.isfinite(d) & (d > 0) & np.all(np.isfinite(px), axis=1)
    if ok.sum() < cfg.min_inliers:
        return None
    px, d = px[ok], d[ok]
    win = (cfg.window_px, cfg.window_px)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
    p0 = px.astype(np.float32).reshape(-1, 1, 2)
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(I0, I1, p0, None, winSize=win, maxLevel=cfg.pyramid_levels,
                                          criteria=criteria)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(I1, I0, p1, None, winSize=win, maxLevel=cfg.pyramid_levels,
                                            criteria=criteria)
    fb = np.linalg.norm((back - p0).reshape(-1, 2), axis=1)
    uv1 = p1.reshape(-1, 2).astype(np.float64)
    tracked = (st1.reshape(-1) == 1) & (st2.reshape(-1) == 1) & (fb < cfg.max_forward_backward_px) \
        & camera.contains(uv1)
    n_tracked = int(tracked.sum())
    if n_tracked < cfg.min_inliers:
        return None
    X = camera.backproject_inverse_depth(px[tracked], d[tracked])
    img_pts = uv1[tracked]
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        X, img_pts, camera.K, None, iterationsCount=cfg.ransac_iterations,
        reprojectionError=cfg.ransac_threshold_px, confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
    n_in = 0 if inliers is None else len(inliers)
    if not found or n_in < cfg.min_inliers:
        return None
    inl = inliers.reshape(-1)
    rvec, tvec = cv2.solvePnPRefineLM(X[inl], img_pts[inl], camera.K, None, rvec, tvec)
    T_frame_keyframe = np.eye(4)
    T_frame_keyframe[:3, :3] = cv2.Rodrigues(rvec)[0]
    T_frame_keyframe[:3, 3] = np.asarray(tvec, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(T_frame_keyframe)):
        return None
    return FlowPose(invert_poses(T_frame_keyframe), n_tracked, n_in)
