"""Front end: point selection and stereo inverse-depth initialisation of keyframes.

* :func:`select_points` picks well-spread, high-gradient pixels (DSO-like).
* :func:`stereo_inverse_depth` finds their inverse depth and variance ``V`` by an epipolar
  search in the right image of a rectified pair (LSD-SLAM-style variance).
* :func:`init_keyframe_points` does both and keeps the points that pass every check.
* :func:`optical_flow_pose` guesses a frame's pose relative to a keyframe from its points'
  sparse optical flow and PnP, for the tracker when the motion model has no guess.

The math, with the names used here, is in ``docs/frontend.md``.
"""

from gtvo.frontend.flow_pose import FlowPose, FlowPoseConfig, optical_flow_pose
from gtvo.frontend.point_selection import (
    DEFAULT_BORDER,
    PointSelectionConfig,
    block_gradient_thresholds,
    gradient_magnitude,
    select_points,
)
from gtvo.frontend.stereo_depth import (
    PATCH_5X5,
    KeyframePoints,
    Rejection,
    StereoDepthResult,
    StereoSearchConfig,
    init_keyframe_points,
    stereo_inverse_depth,
)
from gtvo.frontend.stereo_geometry import disparity_variance, epipolar_direction

__all__ = [
    "DEFAULT_BORDER",
    "FlowPose",
    "FlowPoseConfig",
    "PATCH_5X5",
    "KeyframePoints",
    "PointSelectionConfig",
    "Rejection",
    "StereoDepthResult",
    "StereoSearchConfig",
    "block_gradient_thresholds",
    "disparity_variance",
    "epipolar_direction",
    "gradient_magnitude",
    "init_keyframe_points",
    "optical_flow_pose",
    "select_points",
    "stereo_inverse_depth",
]
