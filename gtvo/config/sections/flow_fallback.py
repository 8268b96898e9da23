"""The ``flow_fallback`` section: the optical-flow + PnP guess tried when tracking fails from every
motion-model guess (:func:`gtvo.frontend.flow_pose.optical_flow_pose`)."""

from __future__ import annotations

from dataclasses import dataclass

from gtvo.core.settings import check_settings, setting
from gtvo.errors import InputError


@dataclass(frozen=True)
class FlowPoseConfig:
    """Settings of :func:`optical_flow_pose`.

    Attributes:
        window_px: Lucas-Kanade window side (pixels, odd).
        pyramid_levels: Lucas-Kanade pyramid levels above the full image (5: 32x coarser, so a
            flow of ~150 px is ~5 px on the top level).
        max_forward_backward_px: largest distance between a point and its flow there and back.
        ransac_threshold_px: PnP RANSAC inlier threshold (reprojection error, pixels).
        ransac_iterations: PnP RANSAC iterations.
        min_inliers: fewest PnP inliers for a guess.
    """

    window_px: int = setting(21, "[3, 101]")
    pyramid_levels: int = setting(5, "[0, 10]")
    max_forward_backward_px: float = setting(1.0, "(0, 100]")
    ransac_threshold_px: float = setting(2.0, "(0, 100]")
    ransac_iterations: int = setting(200, "[1, 100000]")
    min_inliers: int = setting(12, "[4, 100000]")

    def __post_init__(self) -> None:
        check_settings(self)
        if self.window_px < 3 or self.window_px % 2 == 0:
            raise InputError(f"flow window must be odd and >= 3 px, got {self.window_px}")
        if self.pyramid_levels < 0:
            raise InputError(f"flow pyramid levels must be >= 0, got {self.pyramid_levels}")
        if not self.max_forward_backward_px > 0 or not self.ransac_threshold_px > 0:
            raise InputError("flow forward-backward and RANSAC thresholds must be > 0")
        if self.min_inliers < 4 or self.ransac_iterations < 1:
            raise InputError("PnP needs at least 4 inliers and 1 RANSAC iteration")


