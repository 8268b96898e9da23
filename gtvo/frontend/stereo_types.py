"""The stereo front end's types: the search's settings (:class:`StereoSearchConfig`), why a point was
rejected (:class:`Rejection`), the search's result (:class:`StereoDepthResult`) and the points a
keyframe hosts (:class:`KeyframePoints`). The search itself: :mod:`gtvo.frontend.stereo_depth`."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from gtvo.core.settings import SettingError, check_settings, setting

FloatArray = NDArray[np.float64]


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


DEFAULT_STEREO_SEARCH = StereoSearchConfig()


class Rejection(IntEnum):
    """Why a point has no valid depth (``StereoDepthResult.rejection``)."""

    ACCEPTED = 0
    OUTSIDE = 1          #: the pattern leaves the left image, or no candidate fits the right image
    RANGE_BOUNDARY = 2   #: the best integer disparity is the first or last of the search range
    NOT_UNIQUE = 3       #: a second minimum (more than 1 px away) is almost as good
    HIGH_COST = 4        #: the refined mean squared residual is too large for the patch contrast
    REFINEMENT = 5       #: sub-pixel refinement left the +-1 px bracket or the image
    LEFT_RIGHT = 6       #: the right-to-left search does not come back within ``lr_tolerance``
    NON_POSITIVE = 7     #: refined disparity (+ offset) <= 0, i.e. no positive inverse depth
    UNCERTAIN = 8        #: disparity standard deviation above ``max_disparity_std``


@dataclass(frozen=True)
class StereoDepthResult:
    """Per-point output of :func:`stereo_inverse_depth`, all arrays of length N.

    Attributes:
        inverse_depth: ``d = (disparity + disparity_offset) / (fx b)`` (1/m); 0 where invalid.
        variance: inverse-depth variance ``V`` (1/m^2); ``inf`` where invalid.
        valid: True where every check passed.
        disparity: refined disparity ``u_left - u_right`` (px); 0 where not computed.
        cost: mean squared zero-mean residual per pattern pixel at the refined disparity
            (grey levels^2); ``inf`` where not computed.
        disparity_std: ``sigma_disp`` (px); ``inf`` where invalid.
        rejection: a :class:`Rejection` code per point (0 = accepted).
        right_gain: the gain the right image was divided by before this search (1.0 unless
            ``equalize_gain`` found the two cameras' gains to differ).
    """

    inverse_depth: FloatArray
    variance: FloatArray
    valid: NDArray[np.bool_]
    disparity: FloatArray
    cost: FloatArray
    disparity_std: FloatArray
    rejection: NDArray[np.int8]
    right_gain: float = 1.0

    def rejection_counts(self) -> dict[str, int]:
        """Number of points per :class:`Rejection` name."""
        return {r.name: int(np.sum(self.rejection == r)) for r in Rejection}


@dataclass(frozen=True)
class KeyframePoints:
    """The points of one keyframe with a valid stereo depth (what the factors and tracker use).

    Attributes:
        pixels: (N, 2) ``(u, v)`` in the left image (pixel centres are integers).
        inverse_depth: (N,) ``d = 1/z`` in the left camera (1/m), all > 0.
        variance: (N,) inverse-depth variance ``V`` (1/m^2), finite and > 0.
        intensity: (N,) the left image at ``pixels`` (grey levels, float).
    """

    pixels: FloatArray
    inverse_depth: FloatArray
    variance: FloatArray
    intensity: FloatArray

    def __len__(self) -> int:
        return int(self.pixels.shape[0])
