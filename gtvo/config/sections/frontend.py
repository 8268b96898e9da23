"""The ``frontend`` section: how a keyframe gets its points (:class:`PointSelectionConfig`) and their
inverse depths (:class:`StereoSearchConfig`; RGB-D: the depth noise model)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from gtvo.core.settings import SettingError, check_nested, check_settings, setting

#: The fewest points per keyframe :class:`FrontendConfig` accepts.
MIN_POINTS_PER_KEYFRAME = 50
#: Radius of the 8-pixel DSO pattern and of the 5x5 stereo patch.
PATTERN_RADIUS = 2
#: Default free border: pattern radius + 6 px margin (room for the coarse pyramid levels).
DEFAULT_BORDER = PATTERN_RADIUS + 6
#: ``(s0, s2)`` of a structured-light sensor's depth noise ``sigma_z = s0 + s2 z^2`` (m): the
#: default of ``OdometryConfig.frontend.depth_sigma_model``.
DEPTH_SIGMA_MODEL: tuple[float, float] = (0.0012, 0.0019)


@dataclass(frozen=True)
class PointSelectionConfig:
    """Settings of :func:`select_points` (the target count is the caller's: points per keyframe).

    Attributes:
        border: pixels kept free at each image side (pattern radius + a margin for the coarse
            pyramid levels).
        block: side of the threshold blocks (px; DSO: 32).
        threshold_offset: added to each block's median gradient magnitude (grey levels; DSO's
            ``minGradHistAdd`` = 7).
        levels: number of cell levels (s, 2s, 4s, ...).
        downweight: threshold factor per extra cell level.
        max_iterations: iterations adapting the cell size to the target count.
        tolerance: accept a count within ``[target, (1 + tolerance) target]`` without iterating
            further (the surplus is then subsampled away).
        seed: seed of the random subsample.
    """

    border: int = setting(DEFAULT_BORDER, "[0, 1000]")
    block: int = setting(32, "[1, 1024]")
    threshold_offset: float = setting(7.0, "[0, 255]")
    levels: int = setting(3, "[1, 10]")
    downweight: float = setting(0.75, "(0, 1]")
    max_iterations: int = setting(6, "[1, 100]")
    tolerance: float = setting(0.25, "[0, 10]")
    seed: int = setting(0, "[0, 4294967295]")

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class StereoSearchConfig:
    """Settings of the stereo search :func:`stereo_inverse_depth` (its keyword defaults are these).

    Attributes:
        min_disparity: smallest integer disparity searched (px).
        max_disparity: largest integer disparity searched (px).
        pattern: the matching pattern, ``"patch5x5"`` (a full 5x5 patch) or ``"dso8"`` (DSO's 8 pixels).
        disparity_offset: added to the disparity before the conversion to inverse depth, for pairs
            whose principal points differ (Middlebury's ``doffs = cx1 - cx0``); 0 for KITTI-style
            rectification.
        uniqueness_ratio: reject a match when ``best >= uniqueness_ratio * second best`` (second
            best at least 2 px from the best).
        max_relative_cost: reject when the refined mean squared residual per pattern pixel exceeds
            ``2 sigma_intensity^2 + max_relative_cost * var(L)`` (``var(L)``: the left pattern's
            intensity variance).
        gauss_newton_iterations: 1-D Gauss-Newton steps after the parabola fit (0: parabola only).
        left_right_check: search back from the right match into the left image.
        lr_tolerance: allowed left-right discrepancy (px).
        sigma_intensity: image noise standard deviation sigma_I of the disparity variance (grey levels).
        sigma_line: epipolar-line position standard deviation sigma_l (px; rectification error).
        max_disparity_std: reject when the disparity standard deviation exceeds this (px; inf keeps all).
        equalize_gain: when the matched points say the right camera's gain differs from the left's
            by more than 10 %, match again against the right image divided by that gain.
    """

    min_disparity: int = setting(0, "[0, 10000]")
    max_disparity: int = setting(128, "[1, 10000]")
    pattern: Literal["patch5x5", "dso8"] = "patch5x5"
    disparity_offset: float = setting(0.0, "[-10000, 10000]")
    uniqueness_ratio: float = setting(0.9, "(0, 1]")
    max_relative_cost: float = setting(0.4, "[0, 100]")
    gauss_newton_iterations: int = setting(3, "[0, 100]")
    left_right_check: bool = True
    lr_tolerance: float = setting(1.0, "[0, 100]")
    sigma_intensity: float = setting(2.0, "[0, 100]")
    sigma_line: float = setting(0.3, "[0, 100]")
    max_disparity_std: float = setting(2.0, "(0, inf]")
    equalize_gain: bool = True

    def __post_init__(self) -> None:
        check_settings(self)
        if self.min_disparity >= self.max_disparity:
            raise SettingError("max_disparity", f"must be above min_disparity ({self.min_disparity}), "
                                                f"got {self.max_disparity}")


@dataclass(frozen=True)
class FrontendConfig:
    """How a keyframe gets its points and their inverse depths.

    Attributes:
        points_per_keyframe: target number of selected points per keyframe (300: DSO's density of
            2000 active points in a 7-keyframe window; stereo keeps about 60 % of them on KITTI).
            The tracker and the window use the same points; more were measured to be slower and
            no more accurate (docs/benchmarks.md, "Point density").
        points: the point selection (:func:`gtvo.frontend.select_points`).
        stereo: the stereo search (:func:`gtvo.frontend.stereo_inverse_depth`).
        depth_sigma_model: RGB-D only: ``(s0, s2)`` of the depth noise ``sigma_z = s0 + s2 z^2`` (m;
            :func:`gtvo.frontend.rgbd.rgbd_keyframe_points`).
    """

    points_per_keyframe: int = setting(300, f"[{MIN_POINTS_PER_KEYFRAME}, 100000]")
    points: PointSelectionConfig = field(default_factory=PointSelectionConfig)
    stereo: StereoSearchConfig = field(default_factory=StereoSearchConfig)
    depth_sigma_model: tuple[float, float] = setting(DEPTH_SIGMA_MODEL, "[0, 1]")

    def __post_init__(self) -> None:
        check_nested(self)


