"""Compiled loops (numba) of the front end; each is the loop form of numpy code in
:mod:`gtvo.frontend` and is tested against it.

* :func:`pick_cells`: step 3 of the point-selection rule, the hierarchical per-cell pick of the
  pixel of largest gradient above the threshold. The numpy form padded and reshaped two full-size
  arrays per level (about half of ``select_points``' time on KITTI);
* :func:`gradient_norm`: the point selection's gradient magnitude in one pass;
* :func:`bilinear_with_gradient_x`: the stereo refinement's samples of the right image and its x
  gradient, the gradient computed at the sampled corners only;
* :func:`zssd_costs`: the integer epipolar search of :mod:`gtvo.frontend.stereo_depth` (every
  candidate disparity's zero-mean SSD); the numpy form gathered a strip per point and made a
  pass over points x candidates per pattern pixel;
* :func:`block_medians`: the per-block median of the point-selection threshold, exactly
  ``np.median`` over each block (numpy partitioned a transposed copy of the whole image, the largest
  cost of making a keyframe on KITTI): a histogram finds the bin of the middle values, a small sort
  of that bin's values gives them.
"""

from __future__ import annotations

import numpy as np

from gtvo.core.jit import jit


@jit
def pick_cells(score, thr, border, cell, level_factors):
    """Boolean map (H, W) of picks: for each level ``l`` with side ``c = cell * 2^l`` and every
    ``c x c`` cell (the last row / column of cells cut by the image edge) that holds no pick of an
    earlier level, the pixel of largest ``score`` with ``score > thr * level_factors[l]`` within
    ``border`` of no image edge; ties go to the first pixel in row-major order within the cell
    (``np.argmax``'s). ``score``, ``thr`` and ``level_factors`` are float32, compared in float32
    as the numpy form does.

    Which cells hold a pick is kept per level (a cell of level ``l`` is four of level ``l - 1``,
    or the whole image once the side is clamped), so a cell with a pick is not scanned; a pixel is
    compared with the cell's best so far before its threshold (rarely true, so the branch is
    predictable: 3x faster than the threshold first on KITTI, the same picks).
    """
    h, w = score.shape
    picked = np.zeros((h, w), dtype=np.bool_)
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
                for y in range(y0, y1):
                    if y < border or y >= h - border:
                        continue
                    for x in range(x0, x1):
                        if x >= border and x < w - border:
                            s = score[y, x]
                            if s > best and s > thr[y, x] * f:
                                best = s
                                by = y
                                bx = x
                if by >= 0:
                    picked[by, bx] = True
                    has[cy, cx] = True
    return picked


@jit
def zssd_costs(dst, u, v, pu, pv, src_c, s_ll, disparities, sign):
    """The integer epipolar search's ZSSD cost (N, D) of ``stereo_depth._integer_search``.

    Point ``n``'s zero-mean source pattern ``src_c[n]`` (P values at offsets ``(pu, pv)``, float32,
    with ``s_ll[n] = sum src_c^2``) against ``dst`` (float32 (H, W)) at ``(u[n] + sign * d + pu,
    v[n] + pv)`` for every ``d`` of ``disparities``:
    ``s_ll - 2 sum src_c R + sum R^2 - (sum R)^2 / P``, clamped at 0; ``inf`` where a pattern
    sample leaves ``dst``. The sums run over the pattern in order, in float64, as the numpy form
    accumulated them, so the costs are the same to the bit.
    """
    h, w = dst.shape
    n = u.shape[0]
    d_count = disparities.shape[0]
    p = pu.shape[0]
    cost = np.full((n, d_count), np.inf)
    for i in range(n):
        for j in range(d_count):
            base = u[i] + sign * disparities[j]
            inside = True
            s_lr = 0.0
            s_r = 0.0
            s_rr = 0.0
            for k in range(p):
                x = base + pu[k]
                y = v[i] + pv[k]
                if x < 0 or x > w - 1 or y < 0 or y > h - 1:
                    inside = False
                    break
                r = np.float64(dst[y, x])
                s_lr += np.float64(src_c[i, k]) * r
                s_r += r
                s_rr += r * r
            if inside:
                cost[i, j] = max(np.float64(s_ll[i]) - 2.0 * s_lr + s_rr - s_r * s_r / p, 0.0)
    return cost


@jit
def block_medians(image, block):
    """Per ``block`` x ``block`` tile of ``image`` ((nby * block, nbx * block) float32), its median
    as ``np.median`` gives it: the middle value, or for an even count the float32 mean of the two.

    Two passes per tile: a 256-bin histogram between the tile's min and max locates the bins of the
    two middle ranks, then the values of those bins are sorted (a few dozen here).
    """
    nby = image.shape[0] // block
    nbx = image.shape[1] // block
    n = block * block
    out = np.empty((nby, nbx), dtype=np.float32)
    hist = np.zeros(257, dtype=np.int64)
    lo_rank = (n - 1) // 2
    hi_rank = n // 2
    for by in range(nby):
        for bx in range(nbx):
            y0 = by * block
            x0 = bx * block
            vmin = image[y0, x0]
            vmax = vmin
            for y in range(y0, y0 + block):
                for x in range(x0, x0 + block):
                    v = image[y, x]
                    if v < vmin:
                        vmin = v
                    if v > vmax:
                        vmax = v
            if vmax == vmin:
                out[by, bx] = vmin
                continue
            scale = 256.0 / (float(vmax) - float(vmin))
            hist[:] = 0
            for y in range(y0, y0 + block):
                for x in range(x0, x0 + block):
                    hist[min(int((float(image[y, x]) - float(vmin)) * scale), 256)] += 1
            # the bins holding ranks lo_rank and hi_rank, and the count below the first
            below = 0
            b_lo = 0
            while below + hist[b_lo] <= lo_rank:
                below += hist[b_lo]
                b_lo += 1
            b_hi = b_lo
            upto = below + hist[b_lo]
            while upto <= hi_rank:
                b_hi += 1
                upto += hist[b_hi]
            m = 0
            for b in range(b_lo, b_hi + 1):
                m += hist[b]
            vals = np.empty(m, dtype=np.float32)
            k = 0
            for y in range(y0, y0 + block):
                for x in range(x0, x0 + block):
                    v = image[y, x]
                    b = min(int((float(v) - float(vmin)) * scale), 256)
                    if b_lo <= b <= b_hi:
                        vals[k] = v
                        k += 1
            vals.sort()
            a = vals[lo_rank - below]
            c = vals[hi_rank - below]
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
def bilinear_with_gradient_x(img, u, v):
    """``gtvo.core.image.bilinear_sample(np.dstack([img, gx]), u, v)`` (``gx`` the x gradient of
    ``image_gradients``) of a (H >= 2, W >= 2) float32 image at M positions without making ``gx``
    or the stack: the corners' gradients are computed where sampled, the same float32 values, and
    interpolated with the same float64 arithmetic and validity rule as
    ``gtvo.core.image._bilinear_loop``. Returns ``(values (M, 2), valid (M,))``."""
    h, w = img.shape
    m = u.shape[0]
    out = np.zeros((m, 2))
    valid = np.zeros(m, dtype=np.bool_)
    for k in range(m):
        uk, vk = u[k], v[k]
        if not (np.isfinite(uk) and np.isfinite(vk) and uk >= 0.0 and uk <= w - 1 - 0.0
                and vk >= 0.0 and vk <= h - 1 - 0.0):
            continue
        valid[k] = True
        x0 = max(min(int(np.floor(uk)), w - 2), 0)
        y0 = max(min(int(np.floor(vk)), h - 2), 0)
        ax = uk - x0
        ay = vk - y0
        v00, v01, v10, v11 = img[y0, x0], img[y0, x0 + 1], img[y0 + 1, x0], img[y0 + 1, x0 + 1]
        out[k, 0] = (1 - ay) * ((1 - ax) * v00 + ax * v01) + ay * ((1 - ax) * v10 + ax * v11)
        v00, v01 = _gx(img, y0, x0), _gx(img, y0, x0 + 1)
        v10, v11 = _gx(img, y0 + 1, x0), _gx(img, y0 + 1, x0 + 1)
        out[k, 1] = (1 - ay) * ((1 - ax) * v00 + ax * v01) + ay * ((1 - ax) * v10 + ax * v11)
    return out, valid


@jit
def spread_block_thresholds(med, block, h, w, offset):
    """The threshold map (h, w) float32 of ``point_selection.block_gradient_thresholds`` from its
    block medians ``med`` (nby, nbx) float32: each block's 3x3 neighbourhood mean of the medians that
    exist (not NaN, inside the grid), plus ``offset`` (float32), spread over the block's pixels.

    The same arithmetic as its numpy form (``np.nanmean`` over the stack of the 9 shifted, NaN-padded
    grids, ``+ offset``, ``np.repeat``): a float32 sum in the stack's order (NaN and missing blocks
    add 0), divided by the count in float64 and rounded to float32, then the float32 sum with the
    offset.
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
    out = np.empty((h, w), dtype=np.float32)
    for y in range(h):
        row = smooth[y // block]
        for bx in range(nbx):
            t = row[bx]
            for x in range(bx * block, min(bx * block + block, w)):
                out[y, x] = t
    return out
