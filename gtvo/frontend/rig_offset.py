"""The stereo rig's rectification error seen from one stereo pair: the right image's offset.

A rig whose right camera moved against its calibration shows, after rectification, a right image
offset by ``(delta_x, delta_y)`` pixels (docs/window.md, "Rig calibration"; sign: a right image
shifted right by ``s`` px has ``delta_x = s``, its matches sit at ``(u - disparity + delta_x,
v + delta_y)``). A single pair cannot tell ``delta_x`` from depth (it adds to every disparity);
the sliding window estimates it from the temporal residuals. ``delta_y`` makes the rows disagree,
which a pair shows: :func:`estimate_vertical_offset` finds it by a 2-D search, and
:func:`correct_right_image` resamples a right image so that the 1-D stereo search
(:func:`gtvo.frontend.stereo_inverse_depth`) sees a rectified pair.

Whether a pair can carry the offset at all is measured against its own content
(:func:`stereo_contrast`): the offset is a fraction of a pixel read from how the intensity changes
across pixels, and the estimators read it with noise levels fixed in grey levels (the stereo
search's ``sigma_intensity``, the window's ``sigma_I``), so a log too dark or too flat gives
offsets that are artefacts of its low contrast (docs/window.md, "Rig calibration", "Too dark or
too flat to calibrate").
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.core.camera import StereoCamera
from gtvo.core.image import FloatImage, as_float_gray, bilinear_sample, image_gradients, to_float_gray
from gtvo.errors import InputError
from gtvo.frontend.image_noise import image_noise_sigma
from gtvo.frontend.stereo_depth import PATCH_5X5, StereoSearchConfig, stereo_inverse_depth_float

FloatArray = NDArray[np.float64]

#: Fewest matched points for a vertical offset estimate (fewer: no estimate).
MIN_OFFSET_POINTS = 20
#: The rig offset is estimated only when the first pair's points have a median gradient of at
#: least this (grey levels per px). The offset estimates were validated down to 15 (the synthetic
#: logs; EuRoC 23, KITTI 50, the raw drive 57); on KITTI_sequence_1 darkened to a tenth of its
#: exposure (10 grey levels per px) the first pair's vertical offset moves from -0.04..-0.08 px to
#: -0.21..-0.28 px, at a twentieth (5.4) to -0.29..-0.62 px, with its per-point spread unchanged:
#: a bias of the low contrast, not noise (docs/window.md, "Too dark or too flat to calibrate").
MIN_OFFSET_CONTRAST = 12.0
#: ... and a median gradient at least this many times the images' noise (their own, estimated
#: from the image, with the 8-bit quantisation's 1/sqrt(12) grey levels in quadrature): a step of
#: a fifth of a pixel must change a point's intensity by more than the noise.
MIN_OFFSET_CONTRAST_TO_NOISE = 5.0


@dataclass(frozen=True)
class StereoContrast:
    """The contrast a stereo pair's points offer the rig offset (:func:`stereo_contrast`).

    Attributes:
        gradient: the median gradient magnitude of the left image at the points (grey levels / px).
        noise: the left image's noise (:func:`gtvo.frontend.image_noise.image_noise_sigma`) and its
            quantisation (1/sqrt(12) grey levels) in quadrature (grey levels).
    """

    gradient: float
    noise: float

    @property
    def to_noise(self) -> float:
        """``gradient / noise``: how far above the noise a one-pixel step at a point rises."""
        return self.gradient / self.noise if self.noise > 0 else float("inf")

    def too_weak(self) -> str | None:
        """Why the pair cannot carry the rig offset (one line), or None when it can:
        :data:`MIN_OFFSET_CONTRAST`, :data:`MIN_OFFSET_CONTRAST_TO_NOISE`."""
        figures = (f"median gradient {self.gradient:.1f} grey levels per px at the points, "
                   f"{self.to_noise:.1f} times the images' noise of {self.noise:.2f}")
        if self.gradient < MIN_OFFSET_CONTRAST:
            return (f"the images are too dark or too flat to calibrate the rig ({figures}; at least "
                    f"{MIN_OFFSET_CONTRAST:g} grey levels per px needed)")
        if self.to_noise < MIN_OFFSET_CONTRAST_TO_NOISE:
            return (f"the images are too noisy for their contrast to calibrate the rig ({figures}; at least "
                    f"{MIN_OFFSET_CONTRAST_TO_NOISE:g} times needed)")
        return None


def stereo_contrast(left: ArrayLike, pixels: ArrayLike) -> StereoContrast:
    """The :class:`StereoContrast` of a left image (grey levels) at its selected ``pixels`` (N, 2)."""
    img = as_float_gray(left, "left image")
    px = np.asarray(pixels, dtype=float).reshape(-1, 2)
    gx, gy = image_gradients(img)
    u = np.clip(np.rint(px[:, 0]).astype(int), 0, img.shape[1] - 1)
    v = np.clip(np.rint(px[:, 1]).astype(int), 0, img.shape[0] - 1)
    gradient = float(np.median(np.hypot(gx[v, u], gy[v, u]))) if len(px) else 0.0
    return StereoContrast(gradient, float(np.hypot(image_noise_sigma(img), 1.0 / np.sqrt(12.0))))


@dataclass(frozen=True)
class VerticalOffset:
    """The estimate of :func:`estimate_vertical_offset`.

    Attributes:
        delta_y: the right image's vertical offset (px).
        sigma: its standard error (1.4826 MAD / sqrt(n) of the per-point estimates, px).
        n_points: matched points it rests on.
        rows_searched: the whole-row shifts tried, with the matches each accepted.
    """

    delta_y: float
    sigma: float
    n_points: int
    rows_searched: dict[int, int]


def correct_right_image(right: ArrayLike, offset: ArrayLike | None) -> NDArray[np.float32]:
    """The right image resampled as the rectified rig would have seen it: ``R'(u, v) = R(u + dx, v + dy)``
    (bilinear, border replicated). A zero or None offset returns the gray image unchanged."""
    return correct_right_image_float(to_float_gray(right, "right image"), offset)


def correct_right_image_float(img: FloatImage, offset: ArrayLike | None) -> NDArray[np.float32]:
    """:func:`correct_right_image` of an image :func:`gtvo.core.image.to_float_gray` made already (a
    frame's image, converted where it was read), not converted or checked again."""
    if offset is None:
        return img
    dx, dy = (float(x) for x in np.asarray(offset, dtype=float).reshape(2))
    if not (np.isfinite(dx) and np.isfinite(dy)):
        raise InputError(f"rig offset must be finite, got {(dx, dy)!r}")
    if dx == 0.0 and dy == 0.0:
        return img
    M = np.array([[1.0, 0.0, -dx], [0.0, 1.0, -dy]], dtype=np.float64)
    return cv2.warpAffine(img, M, (img.shape[1], img.shape[0]), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)


def _refine_points(left: NDArray[np.float32], right: NDArray[np.float32], pixels: FloatArray,
                   disparity: FloatArray, dy0: float, iterations: int = 6) -> tuple[FloatArray, FloatArray]:
    """Per point, the zero-mean SSD Gauss-Newton over ``(disparity, delta_y)`` of its 5x5 patch,
    from ``(disparity, dy0)``: returns ``(delta_y (N,), smallest eigenvalue of the 2x2 normal matrix (N,))``
    (NaN where the patch leaves the image).

    Symmetric: the left patch is sampled at ``(u + disp/2, v - dy/2)`` and the right one at
    ``(u - disp/2, v + dy/2)``, so both are equally smoothed by the bilinear interpolation (sampling
    only the right image pulls sub-pixel offsets towards whole pixels: 0.5 px was found as 0.25).
    """
    pat = PATCH_5X5.astype(float)
    u = pixels[:, :1] + pat[None, :, 0]
    v = pixels[:, 1:] + pat[None, :, 1]
    lstack = np.dstack([left, *image_gradients(left)])
    rstack = np.dstack([right, *image_gradients(right)])
    disp = disparity.astype(float).copy()
    dy = np.full(disp.shape, float(dy0))
    ok = np.ones(disp.shape, dtype=bool)
    lam_min = np.zeros(disp.shape)

    def centred(x: NDArray) -> NDArray:
        return x - x.mean(axis=1, keepdims=True)

    for _ in range(iterations):
        lv, lok = bilinear_sample(lstack, u + 0.5 * disp[:, None], v - 0.5 * dy[:, None])
        rv, rok = bilinear_sample(rstack, u - 0.5 * disp[:, None], v + 0.5 * dy[:, None])
        ok &= lok.all(axis=1) & rok.all(axis=1)
        r = centred(rv[..., 0]) - centred(lv[..., 0])
        jx = -0.5 * (centred(rv[..., 1]) + centred(lv[..., 1]))  # d r / d disparity
        jy = 0.5 * (centred(rv[..., 2]) + centred(lv[..., 2]))  # d r / d delta_y
        a, b, c = np.sum(jx * jx, 1), np.sum(jx * jy, 1), np.sum(jy * jy, 1)
        ga, gb = np.sum(jx * r, 1), np.sum(jy * r, 1)
        det = a * c - b * b
        good = ok & (det > 1e-9)
        dets = np.where(good, det, 1.0)
        step_d = np.where(good, -(c * ga - b * gb) / dets, 0.0)
        step_y = np.where(good, -(a * gb - b * ga) / dets, 0.0)
        disp += np.clip(step_d, -0.5, 0.5)
        dy += np.clip(step_y, -0.5, 0.5)
        lam_min = 0.5 * (a + c) - np.sqrt(np.maximum(0.25 * (a - c) ** 2 + b * b, 0.0))
    return np.where(ok, dy, np.nan), np.where(ok, lam_min, 0.0)


def estimate_vertical_offset(left: ArrayLike, right: ArrayLike, stereo_camera: StereoCamera, pixels: ArrayLike, *,
                             max_disparity: int = 128, search_rows: int = 2) -> VerticalOffset | None:
    """The right image's vertical offset ``delta_y`` from one stereo pair (a 2-D stereo search).

    1. The 1-D stereo search (:func:`stereo_inverse_depth`) against the right image moved by the
       whole row shifts ``k`` = -1, 0, 1, and further out (up to ``search_rows``) while the best
       is at the edge and the next accepts more; the shift that accepts most matches is kept (a
       row offset of a pixel or more loses many 1-D matches). When step 2 finds the offset more
       than half a row from ``k``, the search runs once more on the nearest row and step 2 is
       repeated there if it accepts more matches.
    2. Each accepted match is refined by a zero-mean SSD Gauss-Newton over its disparity and its
       vertical offset (5x5 patch, bilinear, raw right image); the points whose patch constrains
       both directions (the 2x2 normal matrix's smaller eigenvalue above its median over the
       points: horizontal edges alone say nothing about the disparity, vertical ones nothing about
       ``delta_y``) vote, and the median of their offsets is the estimate. Both patches are
       sampled half-way (:func:`_refine_points`): sub-pixel matching on one bilinear image is
       biased towards whole pixels.

    Returns None when fewer than :data:`MIN_OFFSET_POINTS` points match at any row shift or vote
    (the shift is too large for any stereo match to survive, or the images hold no texture).
    """
    return estimate_vertical_offset_float(to_float_gray(left, "left image"), to_float_gray(right, "right image"),
                                          stereo_camera, pixels, max_disparity=max_disparity, search_rows=search_rows)


def estimate_vertical_offset_float(left_f: FloatImage, right_f: FloatImage, stereo_camera: StereoCamera,
                                   pixels: ArrayLike, *, max_disparity: int = 128,
                                   search_rows: int = 2) -> VerticalOffset | None:
    """:func:`estimate_vertical_offset` of a pair :func:`gtvo.core.image.to_float_gray` made already
    (a frame's images, converted where they were read), not converted or checked again."""
    px = np.asarray(pixels, dtype=float).reshape(-1, 2)
    if int(search_rows) < 0:
        raise InputError(f"search_rows must be >= 0, got {search_rows}")
    counts: dict[int, int] = {}
    results = {}

    def search(k: int) -> None:
        results[k] = stereo_inverse_depth_float(left_f, correct_right_image_float(right_f, (0.0, k)), stereo_camera,
                                                px, StereoSearchConfig(max_disparity=max_disparity))
        counts[k] = int(np.count_nonzero(results[k].valid))

    for k in (-1, 0, 1)[1 - min(int(search_rows), 1):2 + min(int(search_rows), 1)]:
        search(k)
    k = max(counts, key=lambda j: counts[j])
    while k != 0 and abs(k) < int(search_rows) and (k + np.sign(k)) not in counts:  # the best at the edge: go on
        search(int(k + np.sign(k)))
        if counts[int(k + np.sign(k))] <= counts[k]:
            break
        k = int(k + np.sign(k))
    if counts[k] < MIN_OFFSET_POINTS:
        return None
    est = _vote(left_f, right_f, px, results[k], k, counts)
    if est is not None and abs(est.delta_y - k) > 0.5:
        r = int(round(est.delta_y))  # matched a row off: match again on the nearest row, refine from there
        if r not in counts and abs(r) <= int(search_rows):
            search(r)
            if counts[r] > counts[k]:
                return _vote(left_f, right_f, px, results[r], r, counts) or est
    return est


def _vote(left: NDArray[np.float32], right: NDArray[np.float32], px: FloatArray, res, k: int,
          counts: dict[int, int]) -> VerticalOffset | None:
    """Step 2 of :func:`estimate_vertical_offset` for the matches ``res`` found at row shift ``k``."""
    sel = res.valid
    dy, lam = _refine_points(left, right, px[sel], res.disparity[sel], float(k))
    ok = np.isfinite(dy) & (np.abs(dy - k) < 1.0)
    if not np.any(ok):
        return None
    ok &= lam >= np.median(lam[ok])
    n = int(np.count_nonzero(ok))
    if n < MIN_OFFSET_POINTS:
        return None
    est = float(np.median(dy[ok]))
    mad = float(np.median(np.abs(dy[ok] - est)))
    return VerticalOffset(est, 1.4826 * mad / np.sqrt(n), n, dict(counts))
