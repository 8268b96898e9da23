"""The stereo front end's types: the search's settings (:class:`StereoSearchConfig`), why a point was
rejected (:class:`Rejection`), the search's result (:class:`StereoDepthResult`) and the points a
keyframe hosts (:class:`KeyframePoints`). The search itself: :mod:`gtvo.frontend.stereo_depth`."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from gtvo.config.sections.frontend import StereoSearchConfig

FloatArray = NDArray[np.float64]


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
