"""Keyframe points from an RGB-D frame: selected pixels with the sensor's depth and its noise model."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gtvo.config.sections.frontend import DEPTH_SIGMA_MODEL
from gtvo.core.timing import timed
from gtvo.frontend.point_selection import DEFAULT_POINT_SELECTION, PointSelectionConfig, select_points_float
from gtvo.frontend.stereo_depth import KeyframePoints



@timed("stereo_search")  # the keyframe's depths (from the sensor): the stereo search's stage
def rgbd_keyframe_points(image: NDArray[np.float32], depth: NDArray[np.float32], target: int,
                         sigma_model: tuple[float, float] = DEPTH_SIGMA_MODEL,
                         selection: PointSelectionConfig = DEFAULT_POINT_SELECTION) -> KeyframePoints:
    """Keyframe points from an RGB-D frame: selected pixels with the sensor's depth.

    The depth noise ``sigma_z = s0 + s2 z^2`` (structured-light sensors) becomes an inverse-depth
    variance ``V = sigma_z^2 / z^4`` (first-order propagation through ``d = 1/z``). ``selection``:
    the point selection's settings (default :class:`PointSelectionConfig`'s). ``image``: float32
    gray as :func:`gtvo.core.image.to_float_gray` makes it (a frame's image), not checked again.
    """
    px = select_points_float(image, target, selection)
    iu = np.rint(px[:, 0]).astype(np.intp)
    iv = np.rint(px[:, 1]).astype(np.intp)
    z = np.asarray(depth, dtype=np.float64)[iv, iu]
    ok = np.isfinite(z) & (z > 0.1) & (z < 10.0)
    px, z = px[ok], z[ok]
    s0, s2 = sigma_model
    sigma = s0 + s2 * z * z
    return KeyframePoints(pixels=px, inverse_depth=1.0 / z, variance=(sigma * sigma) / z ** 4,
                          intensity=np.asarray(image, dtype=np.float64)[iv[ok], iu[ok]])
