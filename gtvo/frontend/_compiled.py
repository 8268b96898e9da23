"""Compiled loops (numba) of the front end; each is the loop form of numpy code in
:mod:`gtvo.frontend` and is tested against it.

* :func:`pick_cells`: step 3 of the point-selection rule, the hierarchical per-cell pick of the
  pixel of largest gradient above the threshold. The numpy form padded and reshaped two full-size
  arrays per level (about half of ``select_points``' time on KITTI);
* :func:`gradient_norm`: the point selection's gradient magnitude in one pass;
* :func:`best_and_second`: the search's best candidate and its uniqueness competitor per point;
* :func:`subpixel_refine`: the stereo refinement's Gauss-Newton loop, per point, with numpy's
  sums (a dozen (N, P) numpy passes per step before);
* :func:`cubic_row_with_slope`: the stereo refinement's cubic samples of the right image along
  its rows and their exact x derivatives;
* :func:`gradients_at`: the left image's gradients at the stereo patterns' pixels only;
* :func:`zssd_costs`: the integer epipolar search of :mod:`gtvo.frontend.stereo_depth` (every
  candidate disparity's zero-mean SSD); the numpy form gathered a strip per point and made a
  pass over points x candidates per pattern pixel;
* :func:`block_medians`: the per-block median of the point-selection threshold, exactly
  ``np.median`` over each block (numpy partitioned a transposed copy of the whole image, the largest
  cost of making a keyframe on KITTI): histograms narrow the values down to the bins of the middle
  ones, a small sort of those gives them;
* :func:`smooth_block_thresholds`: the block thresholds' 3x3 smoothing;
* :func:`noise_gradient`, :func:`values_where_at_most`: the noise estimate's gradient and its
  responses over the smoother half of the pixels (``image_noise``) without numpy's temporaries;
* :func:`damped_system`: the tracker's damped normal matrix and its finiteness in one call instead
  of nine numpy ones (each as costly as the 8x8 system's whole arithmetic);
* :func:`tracker_terms`: one evaluation of the tracker's cost (residuals, weights, Huber terms,
  counts, normal equations) in one call instead of a dozen numpy passes and calls.
"""

from __future__ import annotations

import numpy as np

from factors import _compiled as _fc
from factors import _compiled_sums as _cs
from gtvo.core.jit import jit


@jit
def pick_cells(score, thr, block, border, cell, level_factors):
    """The picks of step 3 of the point-selection rule as flat indices ``y * W + x`` (row-major
    order, as ``np.flatnonzero`` of a pick map): for each level ``l`` with side ``c = cell * 2^l``
    and every ``c x c`` cell (the last row / column of cells cut by the image edge) that holds no
    pick of an earlier level, the pixel of largest ``score`` (H, W) with
    ``score > T * level_factors[l]`` within ``border`` of no image edge; ties go to the first pixel
    in row-major order within the cell (``np.argmax``'s). ``T`` is the threshold of the pixel's
    ``block x block`` block, ``thr[y // block, x // block]`` (``block = 1``: a per-pixel map).
    ``score``, ``thr`` and ``level_factors`` are float32, compared in float32 as the numpy form does.

    Which cells hold a pick is kept per level (a cell of level ``l`` is four of level ``l - 1``,
    or the whole image once the side is clamped), so a cell with a pick is not scanned; a pixel is
    compared with the cell's best so far before its threshold (rarely true, so the branch is
    predictable: 3x faster than the threshold first on KITTI, the same picks). Within a row's run of
    one threshold block that is: the run's largest value (a branch-free pass), and when it beats the
    best so far and the threshold, its first position (what the pixel-by-pixel comparison picks).
    """
    h, w = score.shape
    minus_inf = np.float32(-np.inf)
    picks = np.empty(16, dtype=np.int64)
    count = 0
    c = cell
    has = np.zeros((1, 1), dtype=np.bool_)
    for lvl in range(level_factors.shape[0]):
        # doubled, but no further than one cell over the whole image (no overflow)
        c_new = c if lvl == 0 else min(2 * c, max(h, w, cell))
        ny = (h + c_new - 1) // c_new
        nx = (w + c_new - 1) // c_new
        has_new = np.zeros((ny, nx), dtype=np.bool_)
        if lvl > 0:  # a cell holds a pick when one of the cells it is made of does
            for cy in range(has.shape[0]):
                for cx in range(has.shape[1]):
                    if has[cy, cx]:
                        if c_new == 2 * c:
                            has_new[cy // 2, cx // 2] = True
                        else:  # clamped: one cell over the whole image
                            has_new[0, 0] = True
        c = c_new
        has = has_new
        f = level_factors[lvl]
        for cy in range(ny):
            y0 = cy * c
            y1 = min(y0 + c, h)
            for cx in range(nx):
                if has[cy, cx]:
                    continue
                x0 = cx * c
                x1 = min(x0 + c, w)
                best = np.float32(-1.0)
                by = -1
                bx = -1
                xa = max(x0, border)
                xb = min(x1, w - border)
                for y in range(max(y0, border), min(y1, h - border)):
                    trow = thr[y // block]
                    srow = score[y]
                    xs = xa
                    while xs < xb:  # the row's run in one threshold block
                        xe = min(xb, (xs // block + 1) * block)
                        m = minus_inf
                        for x in range(xs, xe):
                            sx = srow[x]
                            m = sx if sx > m else m
                        if m > best and m > trow[xs // block] * f:
                            x = xs
                            while srow[x] != m:
                                x += 1
                            best = m
                            by = y
                            bx = x
                        xs = xe
                if by >= 0:
                    has[cy, cx] = True
                    if count == picks.shape[0]:
                        grown = np.empty(2 * count, dtype=np.int64)
                        grown[:count] = picks
                        picks = grown
                    picks[count] = by * w + bx
                    count += 1
    return np.sort(picks[:count])


@jit
def zssd_costs(dst, u, v, pu, pv, src_c, s_ll, disparities, sign):
    """The integer epipolar search's ZSSD cost (N, D) of ``stereo_depth._integer_search``.

    Point ``n``'s zero-mean source pattern ``src_c[n]`` (P values at offsets ``(pu, pv)``, float32,
    with ``s_ll[n] = sum src_c^2``) against ``dst`` (float32 (H, W)) at ``(u[n] + sign * d + pu,
    v[n] + pv)`` for every ``d`` of ``disparities``:
    ``s_ll - 2 sum src_c R + sum R^2 - (sum R)^2 / P``, clamped at 0; ``inf`` where a pattern
    sample leaves ``dst``. The sums run over the pattern in order, in float64, as the numpy form
    accumulated them, so the costs are the same to the bit. Whether a candidate's pattern stays
    inside is decided once from the pattern's extent, not per sample.

    For consecutive disparities (``d0, d0 + 1, ...``, the search's) the valid candidates of a point
    are one run of neighbouring columns: four of them are summed at a time, pattern sample by
    pattern sample, from four neighbouring pixels of the row, with the twelve sums in registers
    (1.3-1.8x faster than one candidate at a time; each candidate's sums keep their order).
    Unsigned indices there: numba's check for negative ones is not made.
    """
    h, w = dst.shape
    n = u.shape[0]
    d_count = disparities.shape[0]
    p = pu.shape[0]
    cost = np.full((n, d_count), np.inf)
    if p == 0 or d_count == 0:
        return cost
    pu_min, pu_max, pv_min, pv_max = pu.min(), pu.max(), pv.min(), pv.max()
    step = 1 if sign == 1 or sign == -1 else 0  # 1: consecutive disparities, a unit sign
    for j in range(1, d_count):
        if disparities[j] != disparities[0] + j:
            step = 0
    flat = dst.ravel()
    rowoff = np.empty(p, dtype=np.int64)
    src = np.empty(p)
    # a run's sums in column order: slot m is its candidate j_lo + m (sign +1) or j_hi - m (sign -1)
    s_lr = np.empty(d_count)
    s_r = np.empty(d_count)
    s_rr = np.empty(d_count)
    for i in range(n):
        if v[i] + pv_min < 0 or v[i] + pv_max > h - 1:
            continue
        for k in range(p):
            rowoff[k] = (v[i] + pv[k]) * w + pu[k]
            src[k] = np.float64(src_c[i, k])
        if step == 1:
            # candidate j's column base u + sign * (d0 + j): the valid ones form one range
            j_lo = d_count
            j_hi = -1
            for j in range(d_count):
                base = u[i] + sign * disparities[j]
                if base + pu_min >= 0 and base + pu_max <= w - 1:
                    j_lo = min(j_lo, j)
                    j_hi = max(j_hi, j)
            if j_hi < j_lo:
                continue
            m_count = j_hi - j_lo + 1
            # lowest column base of the range, and slot m's candidate
            if sign > 0:
                col0 = u[i] + disparities[j_lo]
            else:
                col0 = u[i] - disparities[j_hi]
            m = 0
            while m + 4 <= m_count:
                a0 = a1 = a2 = a3 = 0.0
                b0 = b1 = b2 = b3 = 0.0
                c0 = c1 = c2 = c3 = 0.0
                for k in range(p):
                    sk = src[k]
                    o = np.uint64(rowoff[k] + col0 + m)
                    r0 = np.float64(flat[o])
                    r1 = np.float64(flat[o + np.uint64(1)])
                    r2 = np.float64(flat[o + np.uint64(2)])
                    r3 = np.float64(flat[o + np.uint64(3)])
                    a0 += sk * r0
                    a1 += sk * r1
                    a2 += sk * r2
                    a3 += sk * r3
                    b0 += r0
                    b1 += r1
                    b2 += r2
                    b3 += r3
                    c0 += r0 * r0
                    c1 += r1 * r1
                    c2 += r2 * r2
                    c3 += r3 * r3
                s_lr[m] = a0
                s_lr[m + 1] = a1
                s_lr[m + 2] = a2
                s_lr[m + 3] = a3
                s_r[m] = b0
                s_r[m + 1] = b1
                s_r[m + 2] = b2
                s_r[m + 3] = b3
                s_rr[m] = c0
                s_rr[m + 1] = c1
                s_rr[m + 2] = c2
                s_rr[m + 3] = c3
                m += 4
            while m < m_count:
                a0 = b0 = c0 = 0.0
                for k in range(p):
                    r0 = np.float64(flat[rowoff[k] + col0 + m])
                    a0 += src[k] * r0
                    b0 += r0
                    c0 += r0 * r0
                s_lr[m] = a0
                s_r[m] = b0
                s_rr[m] = c0
                m += 1
            sl = np.float64(s_ll[i])
            for m in range(m_count):
                j = j_lo + m if sign > 0 else j_hi - m
                cost[i, j] = max(sl - 2.0 * s_lr[m] + s_rr[m] - s_r[m] * s_r[m] / p, 0.0)
            continue
        for j in range(d_count):
            base = u[i] + sign * disparities[j]
            if base + pu_min < 0 or base + pu_max > w - 1:
                continue
            a = 0.0
            b = 0.0
            c = 0.0
            for k in range(p):
                r = np.float64(flat[rowoff[k] + base])
                a += src[k] * r
                b += r
                c += r * r
            cost[i, j] = max(np.float64(s_ll[i]) - 2.0 * a + c - b * b / p, 0.0)
    return cost


@jit
def _value_range(vals, m):
    """``(min, max)`` of the float32 values ``vals[:m]`` (``(nan, nan)`` when one is NaN): from their
    int32 bit patterns when all are ``>= +0.0`` and none is NaN (the patterns are ordered as the
    floats then, and an integer reduction vectorises: gradient magnitudes), else by comparisons."""
    keys = vals[:m].view(np.int32)
    kmin = keys[0]
    kmax = kmin
    for i in range(m):
        k = keys[i]
        kmin = min(kmin, k)
        kmax = max(kmax, k)
    if kmin >= 0 and kmax <= 0x7F800000:
        pair = np.empty(2, dtype=np.int32)
        pair[0] = kmin
        pair[1] = kmax
        f = pair.view(np.float32)
        return f[0], f[1]
    vmin = vals[0]
    vmax = vmin
    for i in range(m):
        v = vals[i]
        if np.isnan(v):
            return v, v
        if v < vmin:
            vmin = v
        if v > vmax:
            vmax = v
    return vmin, vmax


@jit
def _middle_values(vals, m, lo, hi, hist, bins):
    """The values of ranks ``lo <= hi`` (0-based, ascending) among the float32 ``vals[:m]``
    (reordered in place), exactly: a 256-bin histogram between the min and the max locates the bins
    of the two ranks, their values are kept and the step repeats on them while more than 32 remain
    (equal values end it at once); the rest are sorted (so are values with an infinity). NaN for
    both when a value is NaN (``np.median``'s). ``hist`` (2, 257) and ``bins`` (m,) are work arrays
    (two interleaved histograms: consecutive increments of one bin do not wait for each other)."""
    while True:
        vmin, vmax = _value_range(vals, m)
        if np.isnan(vmin):
            return vmin, vmin
        if vmax == vmin:
            return vmin, vmin
        if m <= 32 or not (np.isfinite(vmin) and np.isfinite(vmax)):
            break
        scale = 256.0 / (float(vmax) - float(vmin))
        fmin = float(vmin)
        for i in range(m):
            bins[i] = min(int((float(vals[i]) - fmin) * scale), 256)
        hist[:] = 0
        even = m - (m & 1)
        for i in range(0, even, 2):
            hist[0, bins[i]] += 1
            hist[1, bins[i + 1]] += 1
        if even < m:
            hist[0, bins[m - 1]] += 1
        below = 0  # the count below bin b_lo, which holds rank lo; b_hi holds rank hi
        b_lo = 0
        count = hist[0, 0] + hist[1, 0]
        while below + count <= lo:
            below += count
            b_lo += 1
            count = hist[0, b_lo] + hist[1, b_lo]
        b_hi = b_lo
        upto = below + count
        while upto <= hi:
            b_hi += 1
            upto += hist[0, b_hi] + hist[1, b_hi]
        kept = 0
        for i in range(m):
            b = bins[i]
            if b_lo <= b <= b_hi:
                vals[kept] = vals[i]
                kept += 1
        if kept == m:  # the two ranks' bins hold every value: sort them
            break
        m = kept
        lo -= below
        hi -= below
    ordered = np.sort(vals[:m])
    return ordered[lo], ordered[hi]


@jit
def _mirrored(i, n):
    """Index ``i >= 0`` of a length-``n`` axis extended by ``np.pad(..., mode="symmetric")``."""
    j = i % (2 * n)
    return j if j < n else 2 * n - 1 - j


@jit
def block_medians(image, block):
    """Per ``block`` x ``block`` tile of the float32 ``image`` (H, W), its median as ``np.median``
    gives it: the middle value, or for an even count the float32 mean of the two
    (:func:`_middle_values` on a copy of the tile). Partial tiles at the bottom / right are
    completed as ``np.pad(image, ((0, -H % block), (0, -W % block)), mode="symmetric")`` would
    (without making that copy): ``(ceil(H / block), ceil(W / block))`` medians.
    """
    h, w = image.shape
    nby = (h + block - 1) // block
    nbx = (w + block - 1) // block
    n = block * block
    out = np.empty((nby, nbx), dtype=np.float32)
    vals = np.empty(n, dtype=np.float32)
    bins = np.empty(n, dtype=np.int32)
    hist = np.zeros((2, 257), dtype=np.int32)
    lo_rank = (n - 1) // 2
    hi_rank = n // 2
    for by in range(nby):
        for bx in range(nbx):
            x0 = bx * block
            k = 0
            for yy in range(by * block, by * block + block):
                y = _mirrored(yy, h)
                if x0 + block <= w:
                    vals[k:k + block] = image[y, x0:x0 + block]
                else:
                    for xx in range(x0, x0 + block):
                        vals[k + xx - x0] = image[y, _mirrored(xx, w)]
                k += block
            a, c = _middle_values(vals, n, lo_rank, hi_rank, hist, bins)
            out[by, bx] = a if lo_rank == hi_rank else (a + c) * np.float32(0.5)
    return out


@jit
def _gx(img, y, x):
    """``image_gradients``' x gradient of ``img`` at ``(y, x)``: the float32 central difference,
    one-sided at the left and right columns."""
    w = img.shape[1]
    if x == 0:
        return img[y, 1] - img[y, 0]
    if x == w - 1:
        return img[y, w - 1] - img[y, w - 2]
    return np.float32(0.5) * (img[y, x + 1] - img[y, x - 1])


@jit
def _gy(img, y, x):
    """``image_gradients``' y gradient of ``img`` at ``(y, x)`` (one-sided at the top and bottom rows)."""
    h = img.shape[0]
    if y == 0:
        return img[1, x] - img[0, x]
    if y == h - 1:
        return img[h - 1, x] - img[h - 2, x]
    return np.float32(0.5) * (img[y + 1, x] - img[y - 1, x])


@jit
def gradient_norm(img):
    """``sqrt(gx^2 + gy^2)`` (H, W) float32 of a (H, W >= 2) float32 image with ``image_gradients``'
    gradients, in one pass and the same float32 arithmetic as ``np.sqrt(gx * gx + gy * gy)``
    (``point_selection.gradient_magnitude``'s numpy form), so equal to the bit."""
    h, w = img.shape
    out = np.empty((h, w), dtype=np.float32)
    half = np.float32(0.5)
    for y in range(h):
        for x in (0, w - 1):
            gx = _gx(img, y, x)
            gy = _gy(img, y, x)
            out[y, x] = np.sqrt(gx * gx + gy * gy)
        if 0 < y < h - 1:
            for x in range(1, w - 1):  # the interior: no border cases
                gx = half * (img[y, x + 1] - img[y, x - 1])
                gy = half * (img[y + 1, x] - img[y - 1, x])
                out[y, x] = np.sqrt(gx * gx + gy * gy)
        else:
            for x in range(1, w - 1):
                gx = half * (img[y, x + 1] - img[y, x - 1])
                gy = _gy(img, y, x)
                out[y, x] = np.sqrt(gx * gx + gy * gy)
    return out


@jit
def gradients_at(img, u, v):
    """``image_gradients`` ``(gx, gy)`` (float32 (M,) each) of a float32 image (H, W) at the integer
    positions ``(u, v)`` (M,), 0 outside the image (and along an axis of length 1): the same float32
    central differences, one-sided at the borders, computed only where asked."""
    h, w = img.shape
    m = u.shape[0]
    gx = np.zeros(m, dtype=np.float32)
    gy = np.zeros(m, dtype=np.float32)
    for k in range(m):
        x, y = u[k], v[k]
        if 0 <= x < w and 0 <= y < h:
            if w >= 2:
                gx[k] = _gx(img, y, x)
            if h >= 2:
                gy[k] = _gy(img, y, x)
    return gx, gy


@jit
def best_and_second(cost):
    """Per row of an (N, D) cost array: the first position ``k`` of its minimum (``np.argmin``),
    that minimum, and the smallest cost more than one position from ``k`` (``inf`` when none): the
    stereo search's uniqueness test in one pass per row instead of three (N, D) numpy passes."""
    n, d_count = cost.shape
    k_best = np.zeros(n, dtype=np.int64)
    best = np.full(n, np.inf)
    second = np.full(n, np.inf)
    for i in range(n):
        k = 0
        b = cost[i, 0]
        for j in range(1, d_count):
            if cost[i, j] < b:
                b = cost[i, j]
                k = j
        s = np.inf
        for j in range(d_count):
            if (j < k - 1 or j > k + 1) and cost[i, j] < s:
                s = cost[i, j]
        k_best[i] = k
        best[i] = b
        second[i] = s
    return k_best, best, second


@jit
def _cubic_at(img, x, y):
    """Keys' cubic convolution (``a = -1/2``) of a float32 (H, W) image along row ``y`` at the real
    column ``x`` and its exact x derivative: ``(valid, value, slope)``; valid when the four taps
    ``floor(x) - 1 .. floor(x) + 2`` and the row are in the image (0, 0 otherwise)."""
    h, w = img.shape
    fx = np.floor(x)
    x0 = int(fx)
    if x0 < 1 or x0 > w - 3 or y < 0 or y > h - 1:
        return False, 0.0, 0.0
    t = x - fx
    t2 = t * t
    t3 = t2 * t
    a = np.float64(img[y, x0 - 1])
    b = np.float64(img[y, x0])
    c = np.float64(img[y, x0 + 1])
    d = np.float64(img[y, x0 + 2])
    val = 0.5 * ((-t3 + 2 * t2 - t) * a + (3 * t3 - 5 * t2 + 2) * b + (-3 * t3 + 4 * t2 + t) * c
                 + (t3 - t2) * d)
    slope = 0.5 * ((-3 * t2 + 4 * t - 1) * a + (9 * t2 - 10 * t) * b + (-9 * t2 + 8 * t + 1) * c
                   + (3 * t2 - 2 * t) * d)
    return True, val, slope


@jit
def cubic_row_with_slope(img, x, v):
    """Keys' cubic convolution (``a = -1/2``) of a float32 (H, W) image along its rows at M real
    columns ``x`` (float64) of integer rows ``v`` (int64), and its exact x derivative: the
    sub-pixel refinement's samples of :mod:`gtvo.frontend.stereo_depth`. A sample is valid when
    its four taps ``floor(x) - 1 .. floor(x) + 2`` and its row are in the image; 0 elsewhere.
    Returns ``(values (M,), slopes (M,), valid (M,))``; the numpy form in
    ``tests/test_stereo_depth.py`` is its reference."""
    m = x.shape[0]
    val = np.zeros(m)
    slope = np.zeros(m)
    valid = np.zeros(m, dtype=np.bool_)
    for k in range(m):
        valid[k], val[k], slope[k] = _cubic_at(img, x[k], v[k])
    return val, slope, valid


@jit
def _centred_samples(right, u, v, pu, pv, d, rv, rs):
    """The right row's cubic samples (into ``rv``) and slopes (``rs``) of one point's pattern at
    disparity ``d``, each less its pattern mean; whether all are inside."""
    p = pu.shape[0]
    ok_all = True
    for k in range(p):
        ok, rv[k], rs[k] = _cubic_at(right, np.float64(u + pu[k]) - d, v + pv[k])
        ok_all &= ok
    mean_v = _cs.pairwise_sum(rv, p) / p
    mean_s = _cs.pairwise_sum(rs, p) / p
    for k in range(p):
        rv[k] = rv[k] - mean_v
        rs[k] = rs[k] - mean_s
    return ok_all


@jit
def subpixel_refine(right, u, v, pu, pv, left_c, disp, work, iterations):
    """The stereo search's sub-pixel Gauss-Newton steps and final residual
    (``stereo_depth._subpixel_stage``'s numpy loop, the same numbers: its sums in numpy's order,
    :func:`factors._compiled_sums.pairwise_sum`; patterns of at least 8 pixels). Per point ``i`` from ``disp[i]``:
    ``iterations`` steps ``-sum(J r) / sum(J^2)`` (clipped to +-0.5 px; none once a sample left
    the image or where ``work`` is False or ``sum(J^2) <= 1e-9``) on
    ``r_k = left_c[i, k] - (R_k - mean R)``, ``J_k = R'_k - mean R'`` (:func:`_cubic_at` of
    ``right`` at ``(u + pu_k - disp, v + pv_k)``), then the mean squared residual at the result.
    Returns ``(disp, mse (inf where a final sample is outside), final samples all inside)``."""
    n = u.shape[0]
    p = pu.shape[0]
    out = disp.copy()
    mse = np.empty(n)
    inside = np.zeros(n, dtype=np.bool_)
    rv = np.empty(p)
    rs = np.empty(p)
    prod = np.empty(p)
    res = np.empty(p)
    for i in range(n):
        d = out[i]
        going = work[i]
        for _ in range(iterations):
            ok_all = _centred_samples(right, u[i], v[i], pu, pv, d, rv, rs)
            for k in range(p):
                res[k] = np.float64(left_c[i, k]) - rv[k]
                prod[k] = rs[k] * rs[k]
            jtj = _cs.pairwise_sum(prod, p)
            step = 0.0
            if going and ok_all and jtj > 1e-9:
                for k in range(p):
                    prod[k] = rs[k] * res[k]
                step = -_cs.pairwise_sum(prod, p) / jtj
            d = d + min(max(step, -0.5), 0.5)
            going = going and ok_all
        ok_all = _centred_samples(right, u[i], v[i], pu, pv, d, rv, rs)
        for k in range(p):
            r = np.float64(left_c[i, k]) - rv[k]
            prod[k] = r * r
        out[i] = d
        inside[i] = ok_all
        mse[i] = _cs.pairwise_sum(prod, p) / p if ok_all else np.inf
    return out, mse, inside


@jit
def smooth_block_thresholds(med, offset):
    """The block thresholds (nby, nbx) float32 of ``point_selection.block_gradient_thresholds``
    from the block medians ``med`` (nby, nbx) float32: each block's 3x3 neighbourhood mean of the
    medians that exist (not NaN, inside the grid), plus ``offset`` (float32).

    The same arithmetic as its numpy form (``np.nanmean`` over the stack of the 9 shifted, NaN-padded
    grids, ``+ offset``): a float32 sum in the stack's order (NaN and missing blocks add 0), divided
    by the count in float64 and rounded to float32, then the float32 sum with the offset.
    """
    nby, nbx = med.shape
    smooth = np.empty((nby, nbx), dtype=np.float32)
    zero = np.float32(0.0)
    for by in range(nby):
        for bx in range(nbx):
            tot = zero
            cnt = 0
            first = True
            for i in range(-1, 2):
                for j in range(-1, 2):
                    y, x = by + i, bx + j
                    v = zero
                    if 0 <= y < nby and 0 <= x < nbx and not np.isnan(med[y, x]):
                        v = med[y, x]
                        cnt += 1
                    if first:
                        tot = v
                        first = False
                    else:
                        tot = tot + v
            mean = np.float64(tot) / np.float64(cnt) if cnt > 0 else np.nan  # nanmean's 0 / 0
            smooth[by, bx] = np.float32(mean) + offset
    return smooth


@jit
def tracker_terms(packed, has_clip, width, height, border, fx, fy, cx, cy, min_depth, R, t, f, d, host_intensity,
                  host_valid, e, b_h, b_t, jacobians, W, weights_given, V, two_sigma2, k, robust, countable,
                  with_affine):
    """One evaluation of the tracker's cost on a level in one pass over the points
    (``tracking._evaluate``'s numpy steps, the same numbers): per point its pattern's residuals
    and target Jacobians (the arithmetic of :func:`factors._compiled.warp_residuals`, target
    only), the variance weights ``W = 1 / (2 sigma_I^2 + J_depth^2 V)`` unless given
    (``weights_given``: frozen for the level), its Huber weight and loss
    (:func:`factors._compiled_sums.point_huber`'s) and, with ``jacobians``, its terms added to
    the normal equations with the weights ``W w`` (:func:`factors._compiled_sums._gram8`'s sums,
    in the same order; an invalid residual, whose Jacobian and residual are 0, adds exactly 0 and
    is skipped). ``countable`` (N, P): the host samples of points with a positive inverse depth.
    No (N, P, 6) Jacobian array is made: the point's rows stay in registers.

    Returns ``(r, valid, W, loss, ints, A, b)``: ``ints`` = (points with a valid pixel, of those
    outliers ``w < 1``, valid pixels, lost pixels); A (8, 8) and b (8,) (6 without
    ``with_affine``), empty without ``jacobians``."""
    n, p = host_intensity.shape
    r = np.zeros((n, p))
    valid = np.zeros((n, p), dtype=np.bool_)
    W_out = W if weights_given else np.empty((n, p))
    loss = np.empty(n)
    ints = np.zeros(4, dtype=np.int64)
    jrow = np.zeros((p, 8))
    jd_pt = np.zeros(p)
    R00, R01, R02 = R[0, 0], R[0, 1], R[0, 2]
    R10, R11, R12 = R[1, 0], R[1, 1], R[1, 2]
    R20, R21, R22 = R[2, 0], R[2, 1], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    sums = _cs.gram8_zero()
    for i in range(n):
        di = d[i]
        good = np.isfinite(di) and di > 0.0
        ds = di if good else 1.0
        seen = False
        for m in range(p):
            jd_pt[m] = 0.0
            if not good:
                if countable[i, m]:
                    ints[3] += 1
                continue
            f0, f1, f2 = f[i, m, 0], f[i, m, 1], f[i, m, 2]
            q0 = R00 * f0 + R01 * f1 + R02 * f2 + ds * t0
            q1 = R10 * f0 + R11 * f1 + R12 * f2 + ds * t1
            q2 = R20 * f0 + R21 * f1 + R22 * f2 + ds * t2
            ok = False
            if q2 > min_depth * ds and host_valid[i, m]:
                iz = 1.0 / q2
                ok, intensity, gx, gy = _fc._bilinear(packed, has_clip, width, height, border,
                                                      fx * q0 * iz + cx, fy * q1 * iz + cy)
            if not ok:
                if countable[i, m]:
                    ints[3] += 1
                continue
            valid[i, m] = True
            seen = True
            ints[2] += 1
            hb = e * (host_intensity[i, m] - b_h)
            r[i, m] = intensity - b_t - hb
            a0 = gx * fx * iz
            a1 = gy * fy * iz
            a2 = -(a0 * q0 + a1 * q1) * iz
            jd_pt[m] = a0 * t0 + a1 * t1 + a2 * t2
            jrow[m, 0] = a1 * q2 - a2 * q1
            jrow[m, 1] = a2 * q0 - a0 * q2
            jrow[m, 2] = a0 * q1 - a1 * q0
            jrow[m, 3] = -ds * a0
            jrow[m, 4] = -ds * a1
            jrow[m, 5] = -ds * a2
            jrow[m, 6] = -hb if with_affine else 0.0
            jrow[m, 7] = -1.0 if with_affine else 0.0
        if not weights_given:
            v = V[i]
            for m in range(p):
                W_out[i, m] = 1.0 / (two_sigma2 + jd_pt[m] * jd_pt[m] * v)
        s = 0.0
        for m in range(p):
            s += W_out[i, m] * r[i, m] * r[i, m]
        x = np.sqrt(s)
        wi = 1.0
        if not robust or x <= k:
            loss[i] = 0.5 * x * x
        else:
            loss[i] = k * x - 0.5 * k * k
            wi = k / x
        if seen:
            ints[0] += 1
            if wi < 1.0:
                ints[1] += 1
        if not (jacobians and seen):
            continue
        for m in range(p):
            if not valid[i, m]:
                continue
            w = W_out[i, m] * wi
            rr = r[i, m]
            k0, k1, k2, k3 = jrow[m, 0], jrow[m, 1], jrow[m, 2], jrow[m, 3]
            k4, k5, k6, k7 = jrow[m, 4], jrow[m, 5], jrow[m, 6], jrow[m, 7]
            sums = _cs.gram8_add(sums, w, rr, k0, k1, k2, k3, k4, k5, k6, k7)
    if not jacobians:
        return r, valid, W_out, loss, ints, np.zeros((0, 0)), np.zeros(0)
    HK, gK = _cs.gram8_arrays(sums)  # the upper triangle from the sums, then mirrored (as _gram8)
    kk = 8 if (with_affine and n > 0) else 6
    return r, valid, W_out, loss, ints, np.ascontiguousarray(HK[:kk, :kk]), np.ascontiguousarray(gK[:kk])


@jit
def noise_gradient(img):
    """The noise estimate's gradient (``image_noise``) of a float32 image (H, W >= 3):
    ``|I(x+1) - I(x-1)| + |I(y+1) - I(y-1)|`` (float32) at the interior pixels, (H - 2, W - 2), in
    one pass (numpy made four temporary images)."""
    h, w = img.shape
    g = np.empty((h - 2, w - 2), dtype=np.float32)
    for y in range(1, h - 1):
        row, up, down, gy = img[y], img[y - 1], img[y + 1], g[y - 1]
        for x in range(1, w - 1):
            gy[x - 1] = abs(row[x + 1] - row[x - 1]) + abs(down[x] - up[x])
    return g


@jit
def values_where_at_most(values, key, limit):
    """``values[key <= limit]`` of two (H, W) arrays (row-major order, the values' dtype) in one pass."""
    h, w = key.shape
    out = np.empty(h * w, dtype=values.dtype)
    n = 0
    for y in range(h):
        ky, vy = key[y], values[y]
        for x in range(w):
            if ky[x] <= limit:
                out[n] = vy[x]
                n += 1
    return out[:n]


@jit
def damped_system(A, b, lam, eps):
    """``A + lam * diag(diag(A)) + eps * I`` of a square ``A`` (``tracking._solve``'s numpy
    expression: the same operations in the same order per element, ``lam * 0`` and ``eps * 0``
    off the diagonal included) and whether it and ``b`` are all finite."""
    n = A.shape[0]
    Ad = np.empty((n, n))
    finite = True
    for i in range(n):
        for j in range(n):
            on = i == j
            v = (A[i, j] + lam * (A[i, i] if on else 0.0)) + eps * (1.0 if on else 0.0)
            Ad[i, j] = v
            finite &= np.isfinite(v)
    for i in range(b.shape[0]):
        finite &= np.isfinite(b[i])
    return Ad, finite
