"""Compiled loops (numba) for the hot path of :mod:`factors.photometric`.

Each is the loop form of vectorised numpy code that stays the reference (tests compare them to it,
and to numerical derivatives through it):

* :func:`sample_stack`: :meth:`GradientImage.sample` (bilinear intensity and gradients, the
  border and clipped-cell validity rule);
* :func:`warp_residuals`: :func:`photometric_residuals` for a :class:`GradientImage` target in
  three tight loops (warp, gather, residuals and Jacobians) instead of about 40 numpy passes;
* :func:`pack_gradient_image`: ``GradientImage``'s record array (intensity, central-difference
  gradients as ``gtvo.core.image.image_gradients``, clipped-cell flag) in one pass over the image;
* :func:`point_huber`: ``weights.point_robust_terms``, each point's Huber weight and loss
  on its whitened pattern norm;
* :func:`accumulate_target`: ``host_points.gauss_newton_sums``, the Gauss-Newton sums of one
  host-target pair (the window's Hessian accumulation before the Schur complement).

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
def _bilinear(packed, has_clip, width, height, border, u, v):
    """Bilinear ``(valid, I, gx, gy)`` at ``(u, v)`` of ``packed`` ((H*W, 4) float32 records
    ``I, gx, gy, clipped cell``, ``GradientImage._packed``).

    Not valid (and zeros) when the sample is within ``border`` of the image edge, not finite, or
    its 2x2 cell touches a clipped pixel (the cell's top-left record says so, checked when
    ``has_clip``): the rule of ``GradientImage.sample``. (A tuple, not an output array: numba
    keeps it in registers, 4x faster.)
    """
    if not (u >= border and u <= width - 1 - border and v >= border and v <= height - 1 - border):
        return False, 0.0, 0.0, 0.0
    x0 = min(int(u), width - 2)
    y0 = min(int(v), height - 2)
    i = y0 * width + x0
    if has_clip and packed[i, 3] != 0.0:
        return False, 0.0, 0.0, 0.0
    ax = u - x0
    ay = v - y0
    j = i + width
    top = packed[i, 0] + ax * (packed[i + 1, 0] - packed[i, 0])
    bot = packed[j, 0] + ax * (packed[j + 1, 0] - packed[j, 0])
    intensity = top + ay * (bot - top)
    top = packed[i, 1] + ax * (packed[i + 1, 1] - packed[i, 1])
    bot = packed[j, 1] + ax * (packed[j + 1, 1] - packed[j, 1])
    gx = top + ay * (bot - top)
    top = packed[i, 2] + ax * (packed[i + 1, 2] - packed[i, 2])
    bot = packed[j, 2] + ax * (packed[j + 1, 2] - packed[j, 2])
    gy = top + ay * (bot - top)
    return True, intensity, gx, gy


@jit
def sample_stack(packed, has_clip, width, height, border, u, v):
    """:func:`_bilinear` at every ``(u[k], v[k])`` (1-D float64): ``(values (M, 3), valid (M,))``,
    values 0 where invalid."""
    m = u.shape[0]
    values = np.zeros((m, 3))
    valid = np.zeros(m, dtype=np.bool_)
    for k in range(m):
        ok, intensity, gx, gy = _bilinear(packed, has_clip, width, height, border, u[k], v[k])
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

    Args: the target's sampler arrays (see :func:`_bilinear`), the target camera's intrinsics,
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
                ok, intensity, gx, gy = _bilinear(packed, has_clip, width, height, border, uv[i, k, 0], uv[i, k, 1])
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
def accumulate_target(J_host, J_affine_host, J_target, J_affine_target, weight, residual, J_depth):
    """Gauss-Newton sums of one host-target pair, the block order ``[host pose, host affine,
    target pose, target affine]`` (6 + 2 + 6 + 2 = 16 columns; without affine Jacobians, i.e.
    ``J_affine_host`` of shape (0, P, 2), the 12 pose columns only).

    With ``J = [J_host, J_affine_host, J_target, J_affine_target]`` per residual (N, P, k),
    ``weight`` (N, P) (W times the point's Huber weight), ``r = residual`` and ``j = J_depth``:
    ``H = sum w J^T J`` (k, k), ``g = sum w J^T r`` (k,), per point ``H_pd = sum_P w j J`` (N, k),
    ``H_dd = sum_P w j^2`` and ``g_d = sum_P w j r`` (N,). The loop form of the numpy sums
    (concatenate, weight, ``J^T J``, einsum) that ``gtvo.window`` and ``factors.smart`` used;
    the tests compare the two. No temporaries: 1.2-1.3x on a whole window optimisation.
    """
    n, p = residual.shape
    aff = J_affine_host.shape[0] == n and n > 0
    k = 16 if aff else 12
    H = np.zeros((k, k))
    g = np.zeros(k)
    H_pd = np.zeros((n, k))
    H_dd = np.zeros(n)
    g_d = np.zeros(n)
    J = np.empty(k)
    t_off = 8 if aff else 6
    for i in range(n):
        for m in range(p):
            w = weight[i, m]
            if w == 0.0:
                continue
            for c in range(6):
                J[c] = J_host[i, m, c]
                J[t_off + c] = J_target[i, m, c]
            if aff:
                J[6] = J_affine_host[i, m, 0]
                J[7] = J_affine_host[i, m, 1]
                J[14] = J_affine_target[i, m, 0]
                J[15] = J_affine_target[i, m, 1]
            r = residual[i, m]
            jd = J_depth[i, m]
            for a in range(k):
                wa = w * J[a]
                g[a] += wa * r
                H_pd[i, a] += wa * jd
                for b in range(a, k):
                    H[a, b] += wa * J[b]
            H_dd[i] += w * jd * jd
            g_d[i] += w * jd * r
    for a in range(k):
        for b in range(a):
            H[a, b] = H[b, a]
    return H, g, H_pd, H_dd, g_d


@jit
def accumulate_pair(J_host, J_affine_host, B, gain, valid, weight, residual, J_depth):
    """:func:`accumulate_target`'s sums (same outputs, same block order) from the host Jacobians alone.

    A photometric residual depends on the two poses only through ``T_target_host``, so its target
    pose Jacobian is its host pose Jacobian mapped by a matrix of the pair (the adjoint,
    ``J_target = J_host B^T`` with ``B = -[[R, [t]x R], [0, R]]`` of ``T_target_host = (R, t)``,
    :func:`factors.host_points.target_jacobian_map`), and its affine Jacobians are ``(hb, gain)``
    (host) and ``(-hb, -1)`` (target) with ``hb = J_affine_host[..., 0]``. So ``J = T K`` with
    the per-residual ``K = [J_host, hb, 1]`` (8 values; without affines, ``J_affine_host`` of
    shape (0, P, 2), the 6 of ``J_host``) and a (16, 8) map ``T`` of the pair: the loop sums
    ``w K K^T`` (36 products per residual instead of 136), ``w K r`` and per point ``w j K``, then
    maps them by ``T``. Only ``valid`` residuals count (the others' Jacobians are zero, but
    ``K``'s constant 1 is not). The sums are scalar locals, which numba keeps in registers (an array
    accumulator is stored on every update: 2.5x slower). Equal to :func:`accumulate_target` up to
    round-off (tested); ``J_target`` is not needed.
    """
    n, p = residual.shape
    aff = J_affine_host.shape[0] == n and n > 0
    kk = 8 if aff else 6
    one = 1.0 if aff else 0.0
    HpdK = np.zeros((n, 8))
    H_dd = np.zeros(n)
    g_d = np.zeros(n)
    h00 = h01 = h02 = h03 = h04 = h05 = h06 = h07 = 0.0
    h11 = h12 = h13 = h14 = h15 = h16 = h17 = 0.0
    h22 = h23 = h24 = h25 = h26 = h27 = 0.0
    h33 = h34 = h35 = h36 = h37 = 0.0
    h44 = h45 = h46 = h47 = 0.0
    h55 = h56 = h57 = 0.0
    h66 = h67 = 0.0
    h77 = 0.0
    g0 = g1 = g2 = g3 = g4 = g5 = g6 = g7 = 0.0
    for i in range(n):
        hd = gd = 0.0
        q0 = q1 = q2 = q3 = q4 = q5 = q6 = q7 = 0.0
        for m in range(p):
            if not valid[i, m]:
                continue
            w = weight[i, m]
            r = residual[i, m]
            jd = J_depth[i, m]
            k0, k1, k2 = J_host[i, m, 0], J_host[i, m, 1], J_host[i, m, 2]
            k3, k4, k5 = J_host[i, m, 3], J_host[i, m, 4], J_host[i, m, 5]
            k6 = J_affine_host[i, m, 0] if aff else 0.0
            k7 = one
            w0 = w * k0
            w1 = w * k1
            w2 = w * k2
            w3 = w * k3
            w4 = w * k4
            w5 = w * k5
            w6 = w * k6
            w7 = w * k7
            g0 += w0 * r
            q0 += w0 * jd
            h00 += w0 * k0; h01 += w0 * k1; h02 += w0 * k2; h03 += w0 * k3
            h04 += w0 * k4; h05 += w0 * k5; h06 += w0 * k6; h07 += w0 * k7
            g1 += w1 * r
            q1 += w1 * jd
            h11 += w1 * k1; h12 += w1 * k2; h13 += w1 * k3; h14 += w1 * k4
            h15 += w1 * k5; h16 += w1 * k6; h17 += w1 * k7
            g2 += w2 * r
            q2 += w2 * jd
            h22 += w2 * k2; h23 += w2 * k3; h24 += w2 * k4; h25 += w2 * k5; h26 += w2 * k6; h27 += w2 * k7
            g3 += w3 * r
            q3 += w3 * jd
            h33 += w3 * k3; h34 += w3 * k4; h35 += w3 * k5; h36 += w3 * k6; h37 += w3 * k7
            g4 += w4 * r
            q4 += w4 * jd
            h44 += w4 * k4; h45 += w4 * k5; h46 += w4 * k6; h47 += w4 * k7
            g5 += w5 * r
            q5 += w5 * jd
            h55 += w5 * k5; h56 += w5 * k6; h57 += w5 * k7
            g6 += w6 * r
            q6 += w6 * jd
            h66 += w6 * k6; h67 += w6 * k7
            g7 += w7 * r
            q7 += w7 * jd
            h77 += w7 * k7
            hd += w * jd * jd
            gd += w * jd * r
        HpdK[i, 0], HpdK[i, 1], HpdK[i, 2], HpdK[i, 3] = q0, q1, q2, q3
        HpdK[i, 4], HpdK[i, 5], HpdK[i, 6], HpdK[i, 7] = q4, q5, q6, q7
        H_dd[i] = hd
        g_d[i] = gd
    HK = np.empty((8, 8))  # upper triangle from the sums, then mirrored
    HK[0, 0:] = (h00, h01, h02, h03, h04, h05, h06, h07)
    HK[1, 1:] = (h11, h12, h13, h14, h15, h16, h17)
    HK[2, 2:] = (h22, h23, h24, h25, h26, h27)
    HK[3, 3:] = (h33, h34, h35, h36, h37)
    HK[4, 4:] = (h44, h45, h46, h47)
    HK[5, 5:] = (h55, h56, h57)
    HK[6, 6:] = (h66, h67)
    HK[7, 7:] = (h77,)
    for a in range(8):
        for b in range(a):
            HK[a, b] = HK[b, a]
    gK = np.array([g0, g1, g2, g3, g4, g5, g6, g7])
    # the map J = T K: host pose (identity), host affine (hb, gain), target pose (B), target affine (-hb, -1)
    k = 16 if aff else 12
    t_off = 8 if aff else 6
    T = np.zeros((k, kk))
    for c in range(6):
        T[c, c] = 1.0
        for j in range(6):
            T[t_off + c, j] = B[c, j]
    if aff:
        T[6, 6] = 1.0
        T[7, 7] = gain
        T[14, 6] = -1.0
        T[15, 7] = -1.0
    TH = T @ np.ascontiguousarray(HK[:kk, :kk])
    H = TH @ T.T
    H = 0.5 * (H + H.T)
    g = T @ np.ascontiguousarray(gK[:kk])
    H_pd = np.ascontiguousarray(HpdK[:, :kk]) @ T.T
    return H, g, H_pd, H_dd, g_d


@jit
def point_huber(weight, residual, k, robust):
    """Per point ``x = sqrt(sum_P w r^2)`` (``weight``, ``residual`` (N, P)): ``(IRLS weight,
    loss)`` of the Huber kernel with threshold ``k`` (``robust`` False: 1 and ``x^2 / 2``), the
    values of ``weights.huber_weight`` / ``huber_loss``."""
    n, p = residual.shape
    w_out = np.ones(n)
    loss = np.empty(n)
    for i in range(n):
        s = 0.0
        for m in range(p):
            s += weight[i, m] * residual[i, m] * residual[i, m]
        x = np.sqrt(s)
        if not robust or x <= k:
            loss[i] = 0.5 * x * x
        else:
            loss[i] = k * x - 0.5 * k * k
            w_out[i] = k / x
    return w_out, loss


@jit
def add_pair_terms(J_host, J_affine_host, B, gain, valid, W, residual, J_depth, k, robust, cols,
                   H, g, H_pd, H_dd, g_d, cost):
    """One host-target pair's part of ``HostPoints.linearize``, in place: each point's Huber weight
    and loss (:func:`point_huber` on ``W``), the pair's sums (:func:`accumulate_pair` with
    ``W`` times the Huber weight) added to the caller's ``H[cols, cols]``, ``g[cols]``,
    ``H_pd[:, cols]``, ``H_dd``, ``g_d``, and the losses to ``cost``. The numpy steps it fuses
    (the weight product, the sums, five scattered additions) are the loop in
    ``HostPoints.linearize`` that linearisations without the pair's pose take; tested equal."""
    w, loss = point_huber(W, residual, k, robust)
    n, p = residual.shape
    weight = np.empty((n, p))
    for i in range(n):
        for m in range(p):
            weight[i, m] = W[i, m] * w[i]
    Ht, gt, Hpdt, Hddt, gdt = accumulate_pair(J_host, J_affine_host, B, gain, valid, weight, residual, J_depth)
    kc = cols.shape[0]
    for a in range(kc):
        g[cols[a]] += gt[a]
        for b in range(kc):
            H[cols[a], cols[b]] += Ht[a, b]
    for i in range(n):
        for a in range(kc):
            H_pd[i, cols[a]] += Hpdt[i, a]
        H_dd[i] += Hddt[i]
        g_d[i] += gdt[i]
        cost[i] += loss[i]


@jit
def pack_gradient_image(img, lo, hi, check_clip):
    """``GradientImage``'s packed records of a (H, W) float32 image (H, W >= 2): per pixel the
    intensity, ``image_gradients``' central differences (one-sided at the borders, the same float32
    arithmetic) and, with ``check_clip``, 1.0 where the bilinear cell with this top-left corner
    touches a pixel at or beyond ``lo`` / ``hi``. Returns ``(packed (H, W, 4), any pixel clipped,
    all finite)``."""
    h, w = img.shape
    packed = np.zeros((h, w, 4), dtype=np.float32)
    half = np.float32(0.5)
    clipped_any = False
    finite = True
    for y in range(h):
        for x in range(w):
            c = img[y, x]
            if not np.isfinite(c):
                finite = False
            packed[y, x, 0] = c
            if x == 0:
                packed[y, x, 1] = img[y, 1] - img[y, 0]
            elif x == w - 1:
                packed[y, x, 1] = img[y, w - 1] - img[y, w - 2]
            else:
                packed[y, x, 1] = half * (img[y, x + 1] - img[y, x - 1])
            if y == 0:
                packed[y, x, 2] = img[1, x] - img[0, x]
            elif y == h - 1:
                packed[y, x, 2] = img[h - 1, x] - img[h - 2, x]
            else:
                packed[y, x, 2] = half * (img[y + 1, x] - img[y - 1, x])
            if check_clip and (c <= lo or c >= hi):
                clipped_any = True
                # this pixel is a corner of the cells whose top-left is (y, x), (y, x-1), (y-1, x), (y-1, x-1)
                for dy in range(2):
                    for dx in range(2):
                        cy, cx = y - dy, x - dx
                        if 0 <= cy < h - 1 and 0 <= cx < w - 1:
                            packed[cy, cx, 3] = 1.0
    return packed, clipped_any, finite
