"""Stereo inverse depth by epipolar search, sub-pixel refinement and an LSD-SLAM variance.

For each selected left pixel ``p = (u, v)`` of a rectified pair (docs/frontend.md):

1. **Epipolar search.** The epipolar direction of the notes, ``(epx, epy) = (-a t3 + t1,
   -b t3 + t2)`` with ``(a, b, 1)`` the bearing of ``p`` and ``t`` the translation of
   ``T_right_left``, is ``(-baseline, 0)``: the line is the row ``v`` and a point of disparity
   ``disp`` sits at ``(u - disp, v)``. Every integer disparity of ``[min_disparity,
   max_disparity]`` is scored by the zero-mean SSD (ZSSD) of a small pattern (5x5 patch by
   default), giving an (N, D) cost array.
2. **Sub-pixel refinement**: a parabola through the costs at the best integer disparity and
   its two neighbours, then ``gauss_newton_iterations`` 1-D Gauss-Newton steps on the
   zero-mean photometric residual ``r_k(disp) = (L_k - mean L) - (R(p + o_k - disp e_x) - mean R)``
   with ``dr_k/d disp = R'_k - mean R'``, ``R`` the right row's cubic interpolant and ``R'`` its
   exact derivative (:func:`_sample_row_cubic`).
3. **Rejection** (:class:`Rejection`): pattern outside an image, the best cost at the end of the
   search range, not unique (``best >= uniqueness_ratio * second best`` away from +-1 px),
   too high a residual for the patch's contrast, refinement wandering more than 1 px, a left-right check failing,
   non-positive inverse depth, or too large a disparity standard deviation.
4. **Variance** (LSD-SLAM, Engel et al. 2013): with the pattern means ``g_ll = mean((g . l)^2)``
   and ``g2 = mean(|g|^2)`` of the left gradients ``g`` and ``l`` the unit epipolar direction,
   ``sigma_disp^2 = sigma_line^2 * g2 / g_ll + 2 sigma_intensity^2 / g_ll`` (geometric +
   photometric disparity error), and ``V = sigma_disp^2 / (fx b)^2`` since ``d = disp / (fx b)``.
5. **Gain equalisation** (``equalize_gain``): when the accepted points' patch contrast says the
   right camera's gain differs from the left's by more than 10 %, the search runs again on the
   right image divided by that gain (:func:`matched_gain`), re-estimated from each new search until
   it settles; ZSSD absorbs offsets, not gains.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.photometric import DEFAULT_CLIP_RANGE, PATTERN_DSO8
from gtvo.core.camera import StereoCamera
from gtvo.core.timing import timed
from gtvo.errors import InputError
from gtvo.frontend._compiled import best_and_second, cubic_row_with_slope, gradients_at, subpixel_refine, zssd_costs
from gtvo.frontend.point_selection import DEFAULT_POINT_SELECTION, PointSelectionConfig, select_points_float
from gtvo.frontend.stereo_geometry import disparity_variance, epipolar_direction
from gtvo.core.image import FloatImage, check_same_size, to_float_gray
from gtvo.frontend.stereo_types import (DEFAULT_STEREO_SEARCH, KeyframePoints, Rejection, StereoDepthResult,
                                       StereoSearchConfig)

FloatArray = NDArray[np.float64]

#: A full 5x5 patch, offsets (du, dv) row by row.
PATCH_5X5: NDArray[np.int64] = np.array(
    [[du, dv] for dv in range(-2, 3) for du in range(-2, 3)], dtype=np.int64)


#: ``equalize_gain`` matches again only above this ``|log gain|`` (10 %): ZSSD's own error from a
#: 10 % gain is small (median 0.05 px against 0.03 px at equal gains, synthetic plane) while at
#: 30 % it rejects half the points; a second search for less is not worth its time.
EQUALIZE_MIN_LOG_GAIN = 0.1
#: ``equalize_gain``'s most extra searches (each with the gain re-estimated from the last one's
#: matches); a 1.6x gain on KITTI settles in 2, a 1.3x one in 1.
EQUALIZE_MAX_SEARCHES = 3
#: Accepted points needed for :func:`matched_gain`.
MIN_GAIN_POINTS = 10


__all__ = ["KeyframePoints", "Rejection", "StereoDepthResult", "StereoSearchConfig", "disparity_variance",
           "epipolar_direction", "init_keyframe_points", "matched_gain", "stereo_inverse_depth"]


def _as_pattern(pattern: ArrayLike | str) -> NDArray[np.int64]:
    if isinstance(pattern, str):
        table = {"patch5x5": PATCH_5X5, "dso8": PATTERN_DSO8}  # dso8: the factors' pattern
        if pattern not in table:
            raise InputError(f"unknown stereo pattern {pattern!r}; use one of {sorted(table)}")
        return table[pattern].astype(np.int64)
    p = np.asarray(pattern)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3 or not np.all(p == np.round(p)):
        raise InputError(f"stereo pattern must be (P >= 3, 2) integer offsets, got shape {p.shape}")
    return p.astype(np.int64)


def _gather_integer(image: NDArray, u: NDArray, v: NDArray) -> tuple[NDArray, NDArray]:
    """Values at integer positions (any equal shapes) and an inside mask; 0 outside."""
    h, w = image.shape
    ok = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    idx = np.where(ok, v * w + u, 0)
    return np.where(ok, image.reshape(-1)[idx], 0.0), ok


def _sample_row_cubic(image: NDArray[np.float32], x: NDArray, v: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Keys' cubic convolution (``a = -1/2``) of ``image`` along its rows at real columns ``x`` of
    integer rows ``v`` (equal shapes): the values, their exact x derivatives and an inside mask
    (all four taps ``floor(x) - 1 .. floor(x) + 2`` in the image; 0 elsewhere). One compiled loop,
    :func:`gtvo.frontend._compiled.cubic_row_with_slope`.

    The sub-pixel refinement's interpolant: it reproduces quadratics, so it smooths a sample between
    pixels little and does not pull the minimum towards or away from whole pixels as bilinear
    sampling does; and its derivative is the derivative of what is sampled (a central-difference
    gradient beside a bilinear value is not, and Gauss-Newton then stops where the two agree, not
    at the cost's minimum: docs/frontend.md, "Sub-pixel refinement").
    """
    x = np.asarray(x, dtype=np.float64)
    shape = x.shape
    vals, slopes, ok = cubic_row_with_slope(np.ascontiguousarray(image, dtype=np.float32),
                                            np.ascontiguousarray(x).reshape(-1),
                                            np.ascontiguousarray(np.broadcast_to(v, shape), dtype=np.int64).reshape(-1))
    return vals.reshape(shape), slopes.reshape(shape), ok.reshape(shape)


def _integer_search(src: NDArray, dst: NDArray, u: NDArray, v: NDArray, pattern: NDArray,
                    disparities: NDArray, sign: int) -> NDArray[np.float64]:
    """ZSSD cost (N, D) of matching ``src`` patterns at integer (u, v) against ``dst`` at
    ``(u + sign * disp, v)``; ``inf`` where a pattern sample leaves ``dst``.

    The cost of every candidate is ``sum Lc^2 - 2 sum Lc R + sum R^2 - (sum R)^2 / P`` with ``Lc``
    the zero-mean source pattern (computed here) and ``R`` the candidate's ``dst`` pattern
    (:func:`gtvo.frontend._compiled.zssd_costs`, one compiled loop over points x candidates;
    its numpy form is the reference in the tests).
    """
    pu, pv = pattern[:, 0], pattern[:, 1]
    src_vals, _ = _gather_integer(src, u[:, None] + pu, v[:, None] + pv)  # (N, P); 0 outside src
    src_c = src_vals - src_vals.mean(axis=1, keepdims=True)
    s_ll = np.sum(src_c * src_c, axis=1)
    return zssd_costs(np.ascontiguousarray(dst, dtype=np.float32), np.ascontiguousarray(u, dtype=np.int64),
                      np.ascontiguousarray(v, dtype=np.int64), np.ascontiguousarray(pu, dtype=np.int64),
                      np.ascontiguousarray(pv, dtype=np.int64), np.ascontiguousarray(src_c), s_ll,
                      np.ascontiguousarray(disparities, dtype=np.int64), int(sign))


def stereo_inverse_depth(left: NDArray, right: NDArray, stereo_camera: StereoCamera, pixels: ArrayLike,
                         config: StereoSearchConfig = DEFAULT_STEREO_SEARCH,
                         clip_range: tuple[float, float] | None = DEFAULT_CLIP_RANGE) -> StereoDepthResult:
    """Inverse depth and its variance ``V`` of left pixels by a search along the right image row.

    The stages of the module docstring, one function each: the integer search
    (:func:`_integer_search_stage`), the sub-pixel refinement (:func:`_subpixel_stage`), the
    left-right check (:func:`_left_right_stage`), the inverse depth and its variance
    (:func:`_inverse_depth_stage`), and the gain equalisation (:func:`_equalized_search`).

    Args:
        left, right: the rectified gray (or BGR) pair, same size as the camera.
        stereo_camera: the rectified rig; ``fx`` and ``baseline`` convert disparity to inverse depth.
        pixels: (N, 2) integer pixel positions ``(u, v)`` in the left image (from :func:`select_points`).
        config: the search's settings (:class:`StereoSearchConfig`: disparity range, pattern,
            rejection thresholds, noise of the variance, gain equalisation).
        clip_range: the grey levels at which the sensors clipped (:func:`matched_gain`; a run's
            ``OdometryConfig.photometric.clip_range``).

    Returns:
        A :class:`StereoDepthResult`; never NaN.
    """
    return stereo_inverse_depth_float(to_float_gray(left, "left image"), to_float_gray(right, "right image"),
                                      stereo_camera, pixels, config, clip_range)


@timed("stereo_search")
def stereo_inverse_depth_float(left_f: FloatImage, right_f: FloatImage, stereo_camera: StereoCamera,
                               pixels: ArrayLike, config: StereoSearchConfig = DEFAULT_STEREO_SEARCH,
                               clip_range: tuple[float, float] | None = DEFAULT_CLIP_RANGE) -> StereoDepthResult:
    """:func:`stereo_inverse_depth` of a pair :func:`gtvo.core.image.to_float_gray` made already (a
    frame's images, converted where they were read), not converted or checked again."""
    px = _checked_pair(left_f, right_f, stereo_camera, pixels)
    pat = _as_pattern(config.pattern)
    result = _match(left_f, right_f, stereo_camera, px, pat, config)
    if not config.equalize_gain:
        return result
    return _equalized_search(left_f, right_f, stereo_camera, px, pat, config, clip_range, result)


def _checked_pair(left_f: FloatImage, right_f: FloatImage, stereo_camera: StereoCamera, pixels: ArrayLike) -> FloatArray:
    """The pixels as an (N, 2) array, checked with the float gray pair's sizes (one-line errors)."""
    check_same_size(left_f, right_f, "stereo pair")
    if left_f.shape != stereo_camera.left.shape:
        raise InputError(f"stereo images are {left_f.shape[1]}x{left_f.shape[0]}, the camera expects "
                         f"{stereo_camera.left.width}x{stereo_camera.left.height}")
    px = np.asarray(pixels, dtype=float)
    if px.ndim != 2 or px.shape[1] != 2:
        raise InputError(f"pixels must have shape (N, 2), got {px.shape}")
    if not np.all(np.isfinite(px)):
        raise InputError("pixels contain NaN or infinite values")
    if not np.all(px == np.round(px)):
        raise InputError("pixels must be integer pixel centres (as select_points returns)")
    return px


def _match(left_f: NDArray[np.float32], right_f: NDArray[np.float32], stereo_camera: StereoCamera, px: FloatArray,
           pat: NDArray[np.int64], config: StereoSearchConfig) -> StereoDepthResult:
    """Stages 1-4 of the module docstring on one right image."""
    n = px.shape[0]
    u = px[:, 0].astype(np.int64)
    v = px[:, 1].astype(np.int64)
    disps = np.arange(int(config.min_disparity), int(config.max_disparity) + 1, dtype=np.int64)
    rej = np.zeros(n, dtype=np.int8)

    # --- left patch, gradients --------------------------------------------------------------
    pu, pv = pat[:, 0], pat[:, 1]
    lu, lv = u[:, None] + pu, v[:, None] + pv
    left_vals, left_ok = _gather_integer(left_f, lu, lv)
    inside = left_ok.all(axis=1)
    rej[~inside] = Rejection.OUTSIDE
    # image_gradients(left_f) at the pattern pixels only, 0 outside
    gx_p, gy_p = (g.reshape(lu.shape) for g in gradients_at(left_f, lu.reshape(-1), lv.reshape(-1)))

    k, best, c_m, c_p = _integer_search_stage(left_f, right_f, u, v, pat, disps, inside, rej, config)
    disp, d_int, mse = _subpixel_stage(right_f, u, v, pat, left_vals, disps, k, best, c_m, c_p, rej, config)
    if config.left_right_check:
        _left_right_stage(left_f, right_f, u, v, pat, disps, disp, rej, config)
    return _inverse_depth_stage(stereo_camera, px, gx_p, gy_p, disp, mse, rej, config)


def _integer_search_stage(left_f: NDArray, right_f: NDArray, u: NDArray, v: NDArray, pat: NDArray,
                          disps: NDArray, inside: NDArray, rej: NDArray, config: StereoSearchConfig
                          ) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Stage 1, the integer epipolar search: per point the best disparity's position ``k`` in
    ``disps``, its cost and its neighbours' costs; ``rej`` marks points outside, at the range's
    boundary and not unique."""
    n = u.shape[0]
    cost = _integer_search(left_f, right_f, u, v, pat, disps, sign=-1)
    cost[~inside] = np.inf
    k, best, second = best_and_second(cost)
    some = np.isfinite(best)
    rej[(rej == 0) & ~some] = Rejection.OUTSIDE
    d_count = disps.size
    boundary = (k == 0) | (k == d_count - 1)
    # The neighbours must exist for the parabola: a best cost beside an inf (image edge) is a boundary too.
    km, kp = np.clip(k - 1, 0, d_count - 1), np.clip(k + 1, 0, d_count - 1)
    c_m, c_p = cost[np.arange(n), km], cost[np.arange(n), kp]
    boundary |= ~np.isfinite(c_m) | ~np.isfinite(c_p)
    rej[(rej == 0) & boundary] = Rejection.RANGE_BOUNDARY
    unique = best < config.uniqueness_ratio * second
    rej[(rej == 0) & ~unique] = Rejection.NOT_UNIQUE
    return k, best, c_m, c_p


def _subpixel_stage(right_f: NDArray, u: NDArray, v: NDArray, pat: NDArray, left_vals: NDArray, disps: NDArray,
                    k: NDArray, best: NDArray, c_m: NDArray, c_p: NDArray, rej: NDArray,
                    config: StereoSearchConfig) -> tuple[NDArray, NDArray, NDArray]:
    """Stage 2, sub-pixel: a parabola, then 1-D Gauss-Newton steps. Returns the disparity, the
    integer one it started from and the refined mean squared residual; ``rej`` marks points whose
    refinement wandered and whose residual is too high for their contrast."""
    work = rej == 0
    c0 = np.where(work, best, 0.0).astype(np.float64)
    cm = np.where(work, c_m, 0.0).astype(np.float64)
    cp = np.where(work, c_p, 0.0).astype(np.float64)
    denom = cm - 2.0 * c0 + cp
    delta = np.where(denom > 0, 0.5 * (cm - cp) / np.where(denom > 0, denom, 1.0), 0.0)
    d_int = disps[k].astype(np.float64)
    disp = d_int + np.clip(delta, -0.5, 0.5)
    disp = np.where(work, disp, 0.0)

    pu, pv = pat[:, 0], pat[:, 1]
    left_c = left_vals - left_vals.mean(axis=1, keepdims=True)
    # numpy's sums are reproduced (pairwise, in blocks of 8) for patterns of 8 pixels and more
    refine = subpixel_refine if pat.shape[0] >= 8 else _refined_numpy
    disp, mse, ok_all = refine(np.ascontiguousarray(right_f, dtype=np.float32), u, v, np.ascontiguousarray(pu),
                               np.ascontiguousarray(pv), np.ascontiguousarray(left_c), disp, work,
                               int(config.gauss_newton_iterations))
    return _judged_refinement(disp, d_int, mse, ok_all, left_c, rej, config)


def _refined_numpy(right_f: NDArray, u: NDArray, v: NDArray, pu: NDArray, pv: NDArray, left_c: NDArray,
                   disp: NDArray, work: NDArray, iterations: int) -> tuple[NDArray, NDArray, NDArray]:
    """The Gauss-Newton steps of stage 2 and the final residual in numpy
    (:func:`gtvo.frontend._compiled.subpixel_refine`'s reference, and its stand-in for patterns of
    fewer than 8 pixels): ``(disp, mse, final samples all inside)``."""
    work = work.copy()
    fu, fv = u[:, None] + pu, v[:, None] + pv
    for _ in range(iterations):
        r_img, r_gx, ok = _sample_row_cubic(right_f, fu - disp[:, None], fv)
        ok_all = ok.all(axis=1)
        res = left_c - (r_img - r_img.mean(axis=1, keepdims=True))
        jac = r_gx - r_gx.mean(axis=1, keepdims=True)
        jtj = np.sum(jac * jac, axis=1)
        step = np.where(work & ok_all & (jtj > 1e-9), -np.sum(jac * res, axis=1) / np.where(jtj > 1e-9, jtj, 1.0),
                        0.0)
        disp = disp + np.clip(step, -0.5, 0.5)
        work &= ok_all
    r_img, _, ok = _sample_row_cubic(right_f, fu - disp[:, None], fv)
    res = left_c - (r_img - r_img.mean(axis=1, keepdims=True))
    ok_all = ok.all(axis=1)
    return disp, np.where(ok_all, np.mean(res * res, axis=1), np.inf), ok_all


def _judged_refinement(disp: NDArray, d_int: NDArray, mse: NDArray, ok_all: NDArray, left_c: NDArray, rej: NDArray,
                       config: StereoSearchConfig) -> tuple[NDArray, NDArray, NDArray]:
    """The end of stage 2: ``rej`` marks the points whose refined disparity ``disp`` wandered more
    than 1 px from ``d_int`` or whose final samples left the image (not ``ok_all``), and those whose
    mean squared residual ``mse`` is too high for their contrast (``left_c``: the zero-mean left patterns)."""
    wandered = (np.abs(disp - d_int) > 1.0) | ~ok_all
    rej[(rej == 0) & wandered] = Rejection.REFINEMENT
    max_mse = 2.0 * config.sigma_intensity ** 2 + config.max_relative_cost * np.mean(left_c * left_c, axis=1)
    rej[(rej == 0) & ~(mse <= max_mse)] = Rejection.HIGH_COST
    return disp, d_int, mse


def _left_right_stage(left_f: NDArray, right_f: NDArray, u: NDArray, v: NDArray, pat: NDArray, disps: NDArray,
                      disp: NDArray, rej: NDArray, config: StereoSearchConfig) -> None:
    """Stage 3, the left-right check: ``rej`` marks the points whose search back from the right
    match into the left image does not return within ``lr_tolerance``."""
    cand = np.nonzero(rej == 0)[0]
    if cand.size:
        ur = np.rint(u[cand] - disp[cand]).astype(np.int64)
        back = _integer_search(right_f, left_f, ur, v[cand], pat, disps, sign=+1)
        kb = np.argmin(back, axis=1)
        u_back = ur + disps[kb]
        bad = (np.abs(u_back - u[cand]) > config.lr_tolerance) | ~np.isfinite(back[np.arange(cand.size), kb])
        rej[cand[bad]] = Rejection.LEFT_RIGHT


def _inverse_depth_stage(stereo_camera: StereoCamera, px: FloatArray, gx_p: NDArray, gy_p: NDArray, disp: NDArray,
                         mse: NDArray, rej: NDArray, config: StereoSearchConfig) -> StereoDepthResult:
    """Stage 4, the inverse depth and its LSD-SLAM variance; ``rej`` marks non-positive and
    too uncertain disparities. The search's result."""
    fxb = stereo_camera.left.fx * stereo_camera.baseline
    total = disp + float(config.disparity_offset)
    rej[(rej == 0) & (total <= 0)] = Rejection.NON_POSITIVE
    line = epipolar_direction(stereo_camera.left.bearing(px), stereo_camera.T_right_left[:3, 3])
    var_disp = disparity_variance(gx_p, gy_p, line, config.sigma_intensity, config.sigma_line)
    std_disp = np.sqrt(var_disp)
    rej[(rej == 0) & ~(std_disp <= config.max_disparity_std)] = Rejection.UNCERTAIN

    valid = rej == 0
    computed = np.isfinite(mse) & (rej != Rejection.OUTSIDE)
    return StereoDepthResult(
        inverse_depth=np.where(valid, total / fxb, 0.0),
        variance=np.where(valid, var_disp / fxb ** 2, np.inf),
        valid=valid,
        disparity=np.where(computed, disp, 0.0),
        cost=np.where(computed, mse, np.inf),
        disparity_std=np.where(valid, std_disp, np.inf),
        rejection=rej,
    )


def _equalized_search(left_f: NDArray[np.float32], right_f: NDArray[np.float32], stereo_camera: StereoCamera,
                      px: FloatArray, pat: NDArray[np.int64], config: StereoSearchConfig,
                      clip_range: tuple[float, float] | None, result: StereoDepthResult) -> StereoDepthResult:
    """Stage 5, the gain equalisation (``equalize_gain``) after the first search's ``result``.

    When the matched points say the right camera's gain against the left (:func:`matched_gain`)
    differs from 1 by more than :data:`EQUALIZE_MIN_LOG_GAIN` in log, the search runs again
    against the right image divided by that gain, and again while the re-estimated gain moves by
    more than that (at most :data:`EQUALIZE_MAX_SEARCHES` extra searches); the search that accepts
    the most points is returned, with the gain it used in ``right_gain``. The zero-mean SSD absorbs
    an offset between the two cameras but not a gain, which two cameras with their own auto
    exposure can have. Measured on a KITTI pair with a known gain applied (docs/frontend.md): 1.3x
    and 1.6x brighter right images (8 % and 15 % of their pixels saturated) are recovered to 1 %;
    at 2x ZSSD matches too few true points to start from, and the gain stays unequalised.

    ZSSD matches worse the further the gain is from 1 (at 2x a flat patch costs as much as the
    true match), so the first estimate falls short of a large gain: search again with the right
    image equalised by the estimate, and re-estimate from the new matches (always against the raw
    right image, whose clipped pixels are still recognisable) until it settles."""
    best, applied = result, 1.0
    gain = matched_gain(left_f, right_f, px, result, pat, clip_range)
    for _ in range(EQUALIZE_MAX_SEARCHES):
        if gain is None or abs(np.log(gain / applied)) <= EQUALIZE_MIN_LOG_GAIN:
            break
        applied = gain
        again = _match(left_f, right_f / np.float32(applied), stereo_camera, px, pat, config)
        # a contrast ratio can also be a difference in sharpness: keep the search that accepts more
        if np.count_nonzero(again.valid) >= np.count_nonzero(best.valid):
            best = replace(again, right_gain=applied)
        gain = matched_gain(left_f, right_f, px, again, pat, clip_range)
    return best


def matched_gain(left: NDArray, right: NDArray, pixels: ArrayLike, result: StereoDepthResult,
                 pattern: ArrayLike | str = DEFAULT_STEREO_SEARCH.pattern,
                 clip_range: tuple[float, float] | None = DEFAULT_CLIP_RANGE) -> float | None:
    """The right camera's gain against the left from the matched points: the median over accepted
    points of the ratio of their patches' intensity standard deviations (right patch at the
    rounded disparity). Patches that touch a clipped pixel (at or beyond ``clip_range``, the
    run's :attr:`factors.params.PhotometricConfig.clip_range`; None: no check) in either image
    are left out: a saturated patch's spread is not its scene's times the gain
    (with a fifth of the brighter image saturated the estimate fell from 1.6 to 1.2). None with
    fewer than :data:`MIN_GAIN_POINTS` accepted, unclipped points of contrast."""
    pat = _as_pattern(pattern)
    px = np.asarray(pixels, dtype=float).reshape(-1, 2)[result.valid]
    if px.shape[0] < MIN_GAIN_POINTS:
        return None
    u = px[:, 0].astype(np.int64)[:, None] + pat[:, 0]
    v = px[:, 1].astype(np.int64)[:, None] + pat[:, 1]
    lvals, lok = _gather_integer(np.asarray(left, dtype=np.float32), u, v)
    ur = u - np.rint(result.disparity[result.valid]).astype(np.int64)[:, None]
    rvals, rok = _gather_integer(np.asarray(right, dtype=np.float32), ur, v)
    sl, sr = lvals.std(axis=1), rvals.std(axis=1)
    ok = lok.all(axis=1) & rok.all(axis=1) & (sl > 2.0) & (sr > 0.0)
    if clip_range is not None:
        lo, hi = clip_range
        ok &= ((lvals > lo) & (lvals < hi)).all(axis=1) & ((rvals > lo) & (rvals < hi)).all(axis=1)
    if np.count_nonzero(ok) < MIN_GAIN_POINTS:
        return None
    return float(np.median(sr[ok] / sl[ok]))


def init_keyframe_points(left: NDArray, right: NDArray, stereo_camera: StereoCamera, target: int = 2000,
                         selection: PointSelectionConfig = DEFAULT_POINT_SELECTION,
                         stereo: StereoSearchConfig = DEFAULT_STEREO_SEARCH,
                         clip_range: tuple[float, float] | None = DEFAULT_CLIP_RANGE) -> KeyframePoints:
    """Select about ``target`` points in the left image and keep those with a valid stereo depth.

    ``selection``: the point selection's settings (:func:`select_points`); ``stereo`` and
    ``clip_range``: the search's (:func:`stereo_inverse_depth`). Typically 60-80 % of the
    selected points survive on KITTI (docs/frontend.md).
    """
    return init_keyframe_points_float(to_float_gray(left, "left image"), to_float_gray(right, "right image"),
                                      stereo_camera, target, selection, stereo, clip_range)


def init_keyframe_points_float(left_f: FloatImage, right_f: FloatImage, stereo_camera: StereoCamera,
                               target: int = 2000, selection: PointSelectionConfig = DEFAULT_POINT_SELECTION,
                               stereo: StereoSearchConfig = DEFAULT_STEREO_SEARCH,
                               clip_range: tuple[float, float] | None = DEFAULT_CLIP_RANGE) -> KeyframePoints:
    """:func:`init_keyframe_points` of a pair :func:`gtvo.core.image.to_float_gray` made already (a
    frame's images, converted where they were read), not converted or checked again."""
    pixels = select_points_float(left_f, target, selection)
    res = stereo_inverse_depth_float(left_f, right_f, stereo_camera, pixels, stereo, clip_range)
    keep = res.valid
    px = pixels[keep]
    return KeyframePoints(
        pixels=px,
        inverse_depth=res.inverse_depth[keep],
        variance=res.variance[keep],
        intensity=left_f[px[:, 1].astype(np.intp), px[:, 0].astype(np.intp)].astype(np.float64),
    )
