"""The brightness of a rig's right camera relative to its left one (front end: used when a keyframe is made)."""

from __future__ import annotations


import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.gtsam_factors import DEFAULT_SIGMA_INTENSITY
from factors.photometric import PATTERN_SINGLE, GradientImage, sample_host, stereo_residuals
from factors.weights import variance_weight
from gtvo.core.camera import PinholeCamera
from gtvo.core.timing import timed

FloatArray = NDArray[np.float64]


@timed("stereo_search")  # the right image's brightness: part of a new keyframe's stereo
def estimate_stereo_affine(camera: PinholeCamera, baseline: float, left: GradientImage, right: GradientImage,
                           pixels: ArrayLike, inverse_depth: ArrayLike, inverse_depth_variance: ArrayLike,
                           pattern: ArrayLike = PATTERN_SINGLE,
                           sigma_intensity: float = DEFAULT_SIGMA_INTENSITY, offset: ArrayLike | None = None
                           ) -> FloatArray:
    """The right image's brightness ``(a, b)`` relative to the left one: ``I_R ~ exp(a) I_L + b``.

    Fitted by weighted least squares over the points' pattern pixels at their stereo matches,
    weights ``W = (2 sigma_I^2 + (dr/dd)^2 V)^-1`` (a pixel on a strong horizontal gradient
    carries the depth's uncertainty), twice, the second time without the pixels whose residual
    exceeds 3 times the first fit's median absolute residual (occlusions, specularities). The two
    cameras of a rig have their own gain (KITTI: about 0.96 with an offset of 2-3 grey levels); a
    stereo term that ignores it pulls depths.
    The default pattern is the point's own pixel, where its stereo match was found (on the
    synthetic rig the 8-pixel pattern biases the log gain by 5e-3, the single pixel by 2e-3).
    ``offset``: the rig's offset ``(delta_x, delta_y)`` of the right image (px;
    :func:`factors.photometric.stereo_residuals`), None: the rectified model.
    Returns ``(0, 0)`` when fewer than 50 pixels are usable.
    """
    pat = np.asarray(pattern, dtype=float).reshape(-1, 2)
    I_L, ok_L = sample_host(left, pixels, pat)
    lin = stereo_residuals(camera, baseline, I_L, ok_L, pixels, inverse_depth, right, (0.0, 0.0), (0.0, 0.0), pat,
                           offset=offset)
    ok = lin.valid
    if np.count_nonzero(ok) < 50:
        return np.zeros(2)
    x = I_L[ok]
    y = lin.residual[ok] + x  # I_R at the match
    sw = np.sqrt(variance_weight(lin.J_depth, inverse_depth_variance, sigma_intensity)[ok])
    keep = np.ones(x.shape[0], dtype=bool)
    gain, offset = 1.0, 0.0
    for _ in range(2):
        A = np.c_[x[keep], np.ones(np.count_nonzero(keep))] * sw[keep, None]
        gain, offset = np.linalg.lstsq(A, y[keep] * sw[keep], rcond=None)[0]
        res = np.abs(y - gain * x - offset)
        keep = res <= 3.0 * max(float(np.median(res)), 1e-6)
    if not (np.isfinite(gain) and gain > 0 and np.isfinite(offset)):
        return np.zeros(2)
    return np.array([np.log(gain), offset])
