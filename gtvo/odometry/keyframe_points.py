"""A new keyframe's points with their inverse depths: from the stereo pair or the RGB-D depth.

Stereo: points selected in the left image get inverse depths and variances from an epipolar search
in the right image (:func:`gtvo.frontend.init_keyframe_points`); when the window estimates the
rig's offset (:class:`gtvo.window.rig.RigOffset`), the right image is first corrected by the
current estimate, and the first pair also gives the estimate's starting ``delta_y`` (a 2-D search,
:func:`gtvo.frontend.rig_offset.estimate_vertical_offset`). RGB-D: the sensor's depth
(:func:`gtvo.frontend.rgbd.rgbd_keyframe_points`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gtvo.config import OdometryConfig
from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.datasets.sequence import Frame
from gtvo.errors import InputError
from gtvo.frontend import KeyframePoints
from gtvo.frontend.point_selection import select_points_float
from gtvo.frontend.rgbd import rgbd_keyframe_points
from gtvo.frontend.rig_offset import (VerticalOffset, correct_right_image_float, estimate_vertical_offset_float,
                                      stereo_contrast)
from gtvo.frontend.stereo_depth import init_keyframe_points_float
from gtvo.odometry.estimates import TooFewPoints
from gtvo.window.rig import RigOffset


def frame_points(frame: Frame, left: NDArray[np.float32], right: NDArray[np.float32] | None,
                 camera: StereoCamera | PinholeCamera, config: OdometryConfig,
                 rig: RigOffset | None = None) -> KeyframePoints:
    """The points ``frame`` would host as a keyframe (``left``, ``right``: its float32 gray images,
    converted once where the frame was read and not checked again; ``right`` None for RGB-D).

    ``rig``: the rig offset the window estimates (stereo), None for the rectified model; the
    first call starts it from the pair's vertical-offset search.

    Raises:
        InputError: the frame lacks the right image (stereo) or the depth image (RGB-D).
        TooFewPoints: the first pair has no stereo match at any vertical offset (with ``rig``).
    """
    cfg = config.frontend
    if isinstance(camera, StereoCamera):
        if right is None:
            raise InputError(f"frame {frame.index}: stereo odometry needs a right image")
        if rig is not None:
            if rig.initial is None:
                start_rig_offset(left, right, camera, config, rig)
            right = correct_right_image_float(right, rig.offset)
        return init_keyframe_points_float(left, right, camera, cfg.points_per_keyframe, cfg.points, cfg.stereo,
                                    config.photometric.clip_range)
    if frame.depth is None:
        raise InputError(f"frame {frame.index}: RGB-D odometry needs a depth image")
    return rgbd_keyframe_points(left, frame.depth, cfg.points_per_keyframe, cfg.depth_sigma_model, cfg.points)


def start_rig_offset(left: NDArray[np.float32], right: NDArray[np.float32], camera: StereoCamera, config: OdometryConfig,
                     rig: RigOffset) -> None:
    """Start ``rig``'s ``delta_y`` from the first stereo pair's vertical offset (a 2-D search), or
    keep it rectified for the run when the pair's contrast cannot carry an offset
    (:func:`gtvo.frontend.rig_offset.stereo_contrast`).

    Raises:
        TooFewPoints: no stereo match survives at any row shift (an InputError on the first frame)
            although the contrast could carry an offset.
    """
    fcfg = config.frontend
    pixels = select_points_float(left, fcfg.points_per_keyframe, fcfg.points)
    withheld = stereo_contrast(left, pixels).too_weak()
    est = estimate_vertical_offset_float(left, right, camera, pixels, max_disparity=fcfg.stereo.max_disparity)
    if est is None and withheld is not None:  # rectified anyway: the keyframe's own stereo search decides
        est = VerticalOffset(float("nan"), float("nan"), 0, {})
    if est is None:
        raise TooFewPoints("the first stereo pair has no stereo match at any vertical offset within "
                           "+-2 rows: the right camera is offset too far from its calibration (or the "
                           "images hold no texture); no rig offset can be estimated")
    rig.start_from(est, withheld)
