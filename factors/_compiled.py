"""Compiled loops (numba) for the hot path of :mod:`factors.photometric`.

Each is the loop form of vectorised numpy code that stays the reference (tests compare them to it,
and to numerical derivatives through it):

* :func:`sample_stack`: :meth:`GradientImage.sample` (the cubic B-spline's intensity and exact
  gradients, the border and clipped-cell validity rule);
* :func:`warp_residuals`: :func:`photometric_residuals` for a :class:`GradientImage` target in
  three tight loops (warp, gather, residuals and Jacobians) instead of about 40 numpy passes;
* :func:`pack_gradient_image`: ``GradientImage``'s record array (the image's cubic B-spline
  coefficients, clipped-cell flag);
(The window's Gauss-Newton sums and Huber terms: :mod:`factors._compiled_sums`.)

Why compiled: the numpy form makes about 40 passes over (N, P) arrays per call, each a
temporary array, and the kernel was about half of a whole VO run (docs/benchmarks.md, "Compiled
photometric kernel"). The arithmetic here is float64 throughout (the numpy sampler it replaced
interpolated in float32: results moved by about 1e-5 grey levels, the KITTI figures not at all).

Compiled on first use and cached on disk (:func:`gtvo.core.jit.jit`).
"""

from __future__ import annotations

import numpy as np

from gtvo.core.jit import jit


@jit
def _mirror(i, n):
    """Index ``i`` of a line of ``n`` samples, mirrored at its ends (``-1 -> 1``, ``n -> n - 2``)."""
    if i < 0:
        return -i
    if i > n - 1:
        return 2 * (n - 1) - i
    return i


@jit
def _spline(packed, has_clip, width, height, border, u, v):
    """Cubic B-spline ``(valid, I, gx, gy)`` at ``(u, v)`` of ``packed`` ((H*W, 2) float32 records
    ``spline coefficient, clipped cell``, ``GradientImage._packed``): the interpolating cubic spline
    of the image (it passes through every pixel) and its exact derivatives.

    ``I = sum_jk wy_j wx_k c[y0 - 1 + j, x0 - 1 + k]`` over the 4 x 4 coefficients around the cell,
    with the cubic B-spline weights ``w(t)`` of ``t = u - x0`` and, for the gradients, their
    derivatives ``w'(t)``; coefficients beyond the image are its mirror (as in the prefilter).
    Not valid (and zeros) when the sample is within ``border`` of the image edge, not finite, or
    its 2x2 cell touches a clipped pixel (the cell's top-left record says so, checked when
    ``has_clip``): the rule of ``GradientImage.sample``. (A tuple, not an output array: numba
    keeps it in registers.)
    """
    if not (u >= border and u <= width - 1 - border and v >= border and v <= height - 1 - border):
        return False, 0.0, 0.0, 0.0
    x0 = min(int(u), width - 2)
    y0 = min(int(v), height - 2)
    if has_clip and packed[y0 * width + x0, 1] != 0.0:
        return False, 0.0, 0.0, 0.0
    tx = u - x0
    ty = v - y0
    sx = 1.0 - tx
    sy = 1.0 - ty
    # cubic B-spline weights of the taps -1, 0, 1, 2 and their derivatives
    wx0, wx1, wx2, wx3 = sx * sx * sx / 6.0, (3.0 * tx * tx * (tx - 2.0) + 4.0) / 6.0, \
        (3.0 * sx * sx * (sx - 2.0) + 4.0) / 6.0, tx * tx * tx / 6.0
    dx0, dx1, dx2, dx3 = -0.5 * sx * sx, tx * (1.5 * tx - 2.0), -sx * (1.5 * sx - 2.0), 0.5 * tx * tx
    wy0, wy1, wy2, wy3 = sy * sy * sy / 6.0, (3.0 * ty * ty * (ty - 2.0) + 4.0) / 6.0, \
        (3.0 * sy * sy * (sy - 2.0) + 4.0) / 6.0, ty * ty * ty / 6.0
    dy0, dy1, dy2, dy3 = -0.5 * sy * sy, ty * (1.5 * ty - 2.0), -sy * (1.5 * sy - 2.0), 0.5 * ty * ty
    c0, c1, c2, c3 = _mirror(x0 - 1, width), x0, _mirror(x0 + 1, width), _mirror(x0 + 2, width)
    r0, r1, r2, r3 = (_mirror(y0 - 1, height) * width, y0 * width, _mirror(y0 + 1, height) * width,
                      _mirror(y0 + 2, height) * width)
    # the four rows of taps, each as (value along x, its x slope)
    a0, a1, a2, a3 = packed[r0 + c0, 0], packed[r0 + c1, 0], packed[r0 + c2, 0], packed[r0 + c3, 0]
    l0 = wx0 * a0 + wx1 * a1 + wx2 * a2 + wx3 * a3
    s0 = dx0 * a0 + dx1 * a1 + dx2 * a2 + dx3 * a3
    a0, a1, a2, a3 = packed[r1 + c0, 0], packed[r1 + c1, 0], packed[r1 + c2, 0], packed[r1 + c3, 0]
    l1 = wx0 * a0 + wx1 * a1 + wx2 * a2 + wx3 * a3
    s1 = dx0 * a0 + dx1 * a1 + dx2 * a2 + dx3 * a3
    a0, a1, a2, a3 = packed[r2 + c0, 0], packed[r2 + c1, 0], packed[r2 + c2, 0], packed[r2 + c3, 0]
    l2 = wx0 * a0 + wx1 * a1 + wx2 * a2 + wx3 * a3
    s2 = dx0 * a0 + dx1 * a1 + dx2 * a2 + dx3 * a3
    a0, a1, a2, a3 = packed[r3 + c0, 0], packed[r3 + c1, 0], packed[r3 + c2, 0], packed[r3 + c3, 0]
    l3 = wx0 * a0 + wx1 * a1 + wx2 * a2 + wx3 * a3
    s3 = dx0 * a0 + dx1 * a1 + dx2 * a2 + dx3 * a3
    intensity = wy0 * l0 + wy1 * l1 + wy2 * l2 + wy3 * l3
    gx = wy0 * s0 + wy1 * s1 + wy2 * s2 + wy3 * s3
    gy = dy0 * l0 + dy1 * l1 + dy2 * l2 + dy3 * l3
    return True, intensity, gx, gy


@jit
def sample_stack(packed, has_clip, width, height, border, u, v):
    """:func:`_spline` at every ``(u[k], v[k])`` (1-D float64): ``(values (M, 3), valid (M,))``,
    values 0 where invalid."""
    m = u.shape[0]
    values = np.zeros((m, 3))
    valid = np.zeros(m, dtype=np.bool_)
    for k in range(m):
        ok, intensity, gx, gy = _spline(packed, has_clip, width, height, border, u[k], v[k])
        if ok:
            valid[k] = True
            values[k, 0] = intensity
            values[k, 1] = gx
            values[k, 2] = gy
    return values, valid


@jit
def warp_residuals(packed, has_clip, width, height, border, fx, fy, cx, cy, min_depth, R, t, f, d,
                   host_intensity, host_valid, e, b_h, b_t, jacobians, host_jacobians, target_jacobians=True):
    """The loop form of ``photometric_residuals`` (same names, same outputs, same zeros).

    Args: the target's sampler arrays (see :func:`_spline`), the target camera's intrinsics,
    ``MIN_DEPTH``, ``R, t`` of ``T_th`` (float64), bearings ``f`` (N, P, 3), inverse depths
    ``d`` (N,), host intensities and validity (N, P), ``e = exp(a_t - a_h)``, ``b_h``, ``b_t``.

    Three loops over the residuals: warp (arithmetic only), gather (the bilinear samples; a short
    loop body lets the CPU keep many cache misses in flight, 1.5x faster than one fused loop on
    KITTI images, which do not fit the cache), then residuals and Jacobians.

    Returns:
        ``(r, valid, J_depth, uv, J_target, J_host, J_affine_target, J_affine_host, counts)``;
        the Jacobian arrays have 0 rows when not asked for (``jacobians`` False: none;
        ``host_jacobians`` / ``target_jacobians`` False: not those); ``counts`` = (n_bad_depth,
        n_behind, n_outside).
    """
    n, p = host_intensity.shape
    r = np.zeros((n, p))
    valid = np.zeros((n, p), dtype=np.bool_)
    J_depth = np.zeros((n, p))
    uv = np.empty((n, p, 2))
    nj = n if (jacobians and target_jacobians) else 0
    nh = n if (jacobians and host_jacobians) else 0
    J_target = np.zeros((nj, p, 6))
    J_aff_t = np.zeros((nj, p, 2))
    J_host = np.zeros((nh, p, 6))
    J_aff_h = np.zeros((nh, p, 2))
    counts = np.zeros(3, dtype=np.int64)
    R00, R01, R02 = R[0, 0], R[0, 1], R[0, 2]
    R10, R11, R12 = R[1, 0], R[1, 1], R[1, 2]
    R20, R21, R22 = R[2, 0], R[2, 1], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    # phase A: warp every residual (arithmetic only)
    q = np.empty((n, p, 3))
    izs = np.empty((n, p))
    d_safe = np.ones(n)  # the inverse depth, 1 where it is not usable
    state = np.zeros((n, p), dtype=np.int8)  # 0 bad depth, 1 behind, 2 in front
    for i in range(n):
        di = d[i]
        good = np.isfinite(di) and di > 0.0
        if good:
            d_safe[i] = di
        else:
            counts[0] += 1
        ds = d_safe[i]
        for k in range(p):
            f0, f1, f2 = f[i, k, 0], f[i, k, 1], f[i, k, 2]
            q0 = R00 * f0 + R01 * f1 + R02 * f2 + ds * t0
            q1 = R10 * f0 + R11 * f1 + R12 * f2 + ds * t1
            q2 = R20 * f0 + R21 * f1 + R22 * f2 + ds * t2
            front = q2 > min_depth * ds
            iz = 1.0 / q2 if front else 1.0
            q[i, k, 0] = q0
            q[i, k, 1] = q1
            q[i, k, 2] = q2
            izs[i, k] = iz
            uv[i, k, 0] = fx * q0 * iz + cx
            uv[i, k, 1] = fy * q1 * iz + cy
            if good:
                if front:
                    state[i, k] = 2
                else:
                    state[i, k] = 1
                    counts[1] += 1
    # phase B: gather (a tight loop: many loads in flight), only what can become a residual
    S = np.empty((n, p, 3))
    inside = np.zeros((n, p), dtype=np.bool_)
    for i in range(n):
        for k in range(p):
            if state[i, k] == 2 and host_valid[i, k]:
                ok, intensity, gx, gy = _spline(packed, has_clip, width, height, border, uv[i, k, 0], uv[i, k, 1])
                inside[i, k] = ok
                S[i, k, 0] = intensity
                S[i, k, 1] = gx
                S[i, k, 2] = gy
    # phase C: residuals and Jacobians
    for i in range(n):
        ds = d_safe[i]
        for k in range(p):
            if state[i, k] != 2:
                continue
            if not (inside[i, k] and host_valid[i, k]):
                counts[2] += 1
                continue
            f0, f1, f2 = f[i, k, 0], f[i, k, 1], f[i, k, 2]
            q0, q1, q2 = q[i, k, 0], q[i, k, 1], q[i, k, 2]
            iz = izs[i, k]
            intensity, gx, gy = S[i, k, 0], S[i, k, 1], S[i, k, 2]
            valid[i, k] = True
            hb = e * (host_intensity[i, k] - b_h)
            r[i, k] = intensity - b_t - hb
            # a = dr/dq = g^T dw/dq
            a0 = gx * fx * iz
            a1 = gy * fy * iz
            a2 = -(a0 * q0 + a1 * q1) * iz
            J_depth[i, k] = a0 * t0 + a1 * t1 + a2 * t2
            if not jacobians:
                continue
            if target_jacobians:
                J_target[i, k, 0] = a1 * q2 - a2 * q1
                J_target[i, k, 1] = a2 * q0 - a0 * q2
                J_target[i, k, 2] = a0 * q1 - a1 * q0
                J_target[i, k, 3] = -ds * a0
                J_target[i, k, 4] = -ds * a1
                J_target[i, k, 5] = -ds * a2
                J_aff_t[i, k, 0] = -hb
                J_aff_t[i, k, 1] = -1.0
            if not host_jacobians:
                continue
            # a' = R^T a
            p0 = R00 * a0 + R10 * a1 + R20 * a2
            p1 = R01 * a0 + R11 * a1 + R21 * a2
            p2 = R02 * a0 + R12 * a1 + R22 * a2
            J_host[i, k, 0] = f1 * p2 - f2 * p1
            J_host[i, k, 1] = f2 * p0 - f0 * p2
            J_host[i, k, 2] = f0 * p1 - f1 * p0
            J_host[i, k, 3] = ds * p0
            J_host[i, k, 4] = ds * p1
            J_host[i, k, 5] = ds * p2
            J_aff_h[i, k, 0] = hb
            J_aff_h[i, k, 1] = e
    return r, valid, J_depth, uv, J_target, J_host, J_aff_t, J_aff_h, counts


@jit
def _flag_clipped_cells(packed, y, x, h, w):
    """Pixel ``(y, x)`` is clipped: flag the 2x2 cells it is a corner of (top-left at
    ``(y, x)``, ``(y, x-1)``, ``(y-1, x)``, ``(y-1, x-1)``), all written already."""
    for dy in range(2):
        for dx in range(2):
            cy, cx = y - dy, x - dx
            if 0 <= cy < h - 1 and 0 <= cx < w - 1:
                packed[cy, cx, 1] = 1.0


#: the pole of the cubic B-spline's prefilter, ``sqrt(3) - 2``
_SPLINE_POLE = 3.0 ** 0.5 - 2.0
#: samples summed for a causal initial value: ``|z|^24`` is 2e-14 (shorter lines: the exact mirror sum)
_SPLINE_HORIZON = 24


@jit
def _causal_start(line, n, z):
    """The causal recursion's initial value of a line of ``n`` samples, mirror boundaries: the exact
    sum over the mirrored line when it is short, else its first ``_SPLINE_HORIZON`` terms."""
    if n > _SPLINE_HORIZON:
        total = line[0]
        zk = z
        for k in range(1, _SPLINE_HORIZON):
            total += zk * line[k]
            zk *= z
        return total
    zn = z
    z2n = z ** (n - 1)
    total = line[0] + z2n * line[n - 1]
    z2n = z2n * z2n / z
    for k in range(1, n - 1):
        total += (zn + z2n) * line[k]
        zn *= z
        z2n /= z
    return total / (1.0 - zn * zn)


@jit
def pack_gradient_image(img, lo, hi, check_clip):
    """``GradientImage``'s packed records of a (H, W) float32 image (H, W >= 2): per pixel the
    coefficient of the image's interpolating cubic B-spline (mirror boundaries; float64 arithmetic,
    stored float32) and, with ``check_clip``, 1.0 where the 2x2 cell with this top-left corner
    touches a pixel at or beyond ``lo`` / ``hi``. Returns ``(packed (H, W, 2), any pixel clipped,
    all finite)``.

    The prefilter is Unser's recursive one (as in Thevenaz et al.'s "Interpolation revisited"):
    along each row and then each column, a causal and an anticausal first-order recursion of the
    pole ``z`` with their mirror-boundary initial values and the gain 6 per axis. The columns run
    row by row over all columns at once (memory in order)."""
    h, w = img.shape
    packed = np.empty((h, w, 2), dtype=np.float32)
    coef = np.empty((h, w))
    clipped_any = False
    finite = True
    z = _SPLINE_POLE
    tail = z / (z * z - 1.0)
    for y in range(h):
        row = coef[y]
        for x in range(w):
            c = img[y, x]
            row[x] = 36.0 * c  # the gain (1 - z)(1 - 1/z) = 6 of both axes
            packed[y, x, 1] = 0.0
            if not np.isfinite(c):
                finite = False
        if not finite:
            return packed, clipped_any, finite
        row[0] = _causal_start(row, w, z)
        for x in range(1, w):
            row[x] += z * row[x - 1]
        row[w - 1] = tail * (z * row[w - 2] + row[w - 1])
        for x in range(w - 2, -1, -1):
            row[x] = z * (row[x + 1] - row[x])
    # the columns, row by row: the causal initial values (all columns at once), the recursions
    start = np.empty(w)
    column = np.empty(h)
    if h > _SPLINE_HORIZON:
        start[:] = coef[0]
        zk = z
        for k in range(1, _SPLINE_HORIZON):
            for x in range(w):
                start[x] += zk * coef[k, x]
            zk *= z
    else:
        for x in range(w):
            for y in range(h):
                column[y] = coef[y, x]
            start[x] = _causal_start(column, h, z)
    for x in range(w):
        coef[0, x] = start[x]
    for y in range(1, h):
        for x in range(w):
            coef[y, x] += z * coef[y - 1, x]
    for x in range(w):
        coef[h - 1, x] = tail * (z * coef[h - 2, x] + coef[h - 1, x])
        packed[h - 1, x, 0] = coef[h - 1, x]
    for y in range(h - 2, -1, -1):
        for x in range(w):
            coef[y, x] = z * (coef[y + 1, x] - coef[y, x])
            packed[y, x, 0] = coef[y, x]
    if check_clip:
        for y in range(h):
            for x in range(w):
                c = img[y, x]
                if c <= lo or c >= hi:
                    clipped_any = True
                    _flag_clipped_cells(packed, y, x, h, w)
    return packed, clipped_any, finite
