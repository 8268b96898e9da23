"""Compiled loops (numba) of the Gauss-Newton sums of the window and the tracker; each is the loop form of numpy code
that stays the reference (tests compare them to it):

* :func:`point_huber`: ``weights.point_robust_terms``, each point's Huber weight and loss
  on its whitened pattern norm;
* :func:`accumulate_target`: ``host_points.gauss_newton_sums``, the Gauss-Newton sums of one
  host-target pair (the window's Hessian accumulation before the Schur complement);
* :func:`accumulate_pair`: the same sums from the host Jacobians alone (the target ones mapped by
  the pair's ``-Ad^-T``, docs/factors.md §7);
* :func:`add_pair_terms`: ``HostPoints.linearize``'s per-pair loop (Huber terms, sums, scatter
  into the caller's system) in one call;
* :func:`add_depth_terms`: ``HostPoints.linearize``'s depth-only terms (the stereo term's Huber
  terms and sums, the depth prior) added to ``H_dd``, ``g_d`` and the point costs;
* :func:`target_normal_equations`: the tracker's normal equations of a frame pose (and affine).

Compiled on first use and cached on disk (:func:`gtvo.core.jit.jit`).
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from gtvo.core.jit import jit, jit_inline


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


@jit_inline
def gram8_zero():
    """The 44 scalar sums of :func:`gram8_add` (``HK``'s upper triangle row by row, then ``gK``), all zero."""
    return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@jit_inline
def gram8_add(s, w, r, k0, k1, k2, k3, k4, k5, k6, k7):
    """The sums ``s`` (:func:`gram8_zero`'s layout) with one residual ``r`` of weight ``w`` and
    Jacobian row ``K = (k0..k7)`` added: ``HK += w K K^T`` (upper triangle), ``gK += w K r``. A tuple
    of scalars, inlined: numba keeps the sums in registers (an array accumulator is stored on
    every update: 2.5x slower); each sum gets one addition per residual, in the callers' order."""
    (h00, h01, h02, h03, h04, h05, h06, h07, h11, h12, h13, h14, h15, h16, h17, h22, h23, h24, h25, h26, h27, h33, h34, h35, h36, h37, h44, h45, h46, h47, h55, h56, h57, h66, h67, h77, g0, g1, g2, g3, g4, g5, g6, g7) = s
    w0 = w * k0
    w1 = w * k1
    w2 = w * k2
    w3 = w * k3
    w4 = w * k4
    w5 = w * k5
    w6 = w * k6
    w7 = w * k7
    g0 += w0 * r
    h00 += w0 * k0; h01 += w0 * k1; h02 += w0 * k2; h03 += w0 * k3; h04 += w0 * k4; h05 += w0 * k5; h06 += w0 * k6; h07 += w0 * k7
    g1 += w1 * r
    h11 += w1 * k1; h12 += w1 * k2; h13 += w1 * k3; h14 += w1 * k4; h15 += w1 * k5; h16 += w1 * k6; h17 += w1 * k7
    g2 += w2 * r
    h22 += w2 * k2; h23 += w2 * k3; h24 += w2 * k4; h25 += w2 * k5; h26 += w2 * k6; h27 += w2 * k7
    g3 += w3 * r
    h33 += w3 * k3; h34 += w3 * k4; h35 += w3 * k5; h36 += w3 * k6; h37 += w3 * k7
    g4 += w4 * r
    h44 += w4 * k4; h45 += w4 * k5; h46 += w4 * k6; h47 += w4 * k7
    g5 += w5 * r
    h55 += w5 * k5; h56 += w5 * k6; h57 += w5 * k7
    g6 += w6 * r
    h66 += w6 * k6; h67 += w6 * k7
    g7 += w7 * r
    h77 += w7 * k7
    return (h00, h01, h02, h03, h04, h05, h06, h07, h11, h12, h13, h14, h15, h16, h17, h22, h23, h24, h25, h26, h27, h33, h34, h35, h36, h37, h44, h45, h46, h47, h55, h56, h57, h66, h67, h77, g0, g1, g2, g3, g4, g5, g6, g7)


@jit_inline
def gram8_arrays(s):
    """``(HK (8, 8), gK (8,))`` of the sums ``s``: the upper triangle, mirrored."""
    (h00, h01, h02, h03, h04, h05, h06, h07, h11, h12, h13, h14, h15, h16, h17, h22, h23, h24, h25, h26, h27, h33, h34, h35, h36, h37, h44, h45, h46, h47, h55, h56, h57, h66, h67, h77, g0, g1, g2, g3, g4, g5, g6, g7) = s
    HK = np.empty((8, 8))
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
    return HK, np.array([g0, g1, g2, g3, g4, g5, g6, g7])


_V2, _V4, _V8 = (ir.VectorType(ir.DoubleType(), k) for k in (2, 4, 8))
#: :func:`_gram8`'s accumulator block: ``HK`` row by row (8 x 8, all of it), ``gK``, the point's ``HpdK`` row
_ROWS_G, _ROWS_Q, _ACC_SIZE = 64, 72, 80


def _lanes(ks: list[int]) -> ir.Constant:
    """A shuffle mask (LLVM ``<k x i32>`` constant) picking the lanes ``ks``."""
    i32 = ir.IntType(32)
    return ir.Constant(ir.VectorType(i32, len(ks)), [ir.Constant(i32, k) for k in ks])


@intrinsic
def _add_residual8(typingctx, acc, J6, J2, i, m, w, r, jd, aff, per_point):
    """Add one residual to :func:`_gram8`'s sums in ``acc`` (``_ACC_SIZE`` float64), as vectors of 8
    lanes (LLVM ``<8 x double>``: AVX-512 registers where the CPU has them, pairs of AVX ones else).
    With ``K = [J6[i, m, :6], J2[i, m, :2] if aff else (0, 0)]`` and ``wK = w K``: row ``a`` of
    ``HK`` gets ``wK[a] K``, ``gK`` gets ``wK r`` and, with ``per_point``, the point's row gets
    ``wK jd``. Lane by lane these are the scalar products and sums of :func:`gram8_add` (a
    multiplication, then an addition: no fused multiply-add), in the same order, so the same
    values to the bit; only the lower triangle of ``HK``, which :func:`_gram8` does not read, is
    extra work. (numba does not vectorise the scalar form: its SLP vectoriser is off.)
    ``J6``, ``J2``: last axis contiguous."""
    sig = types.void(acc, J6, J2, i, m, w, r, jd, aff, per_point)

    def codegen(context, builder, signature, args):
        acc_t, j6_t, j2_t = signature.args[:3]
        acc_a, j6_a, j2_a = (context.make_array(t)(context, builder, v) for t, v in zip((acc_t, j6_t, j2_t), args[:3]))
        i_v, m_v, w_v, r_v, jd_v, aff_v, pp_v = args[3:]
        i32, i64 = ir.IntType(32), ir.IntType(64)
        zero = context.get_constant(types.intp, 0)

        def item(ty, arr):  # pointer to arr[i, m, 0]
            return cgutils.get_item_pointer2(context, builder, data=arr.data, shape=cgutils.unpack_tuple(builder, arr.shape),
                                             strides=cgutils.unpack_tuple(builder, arr.strides), layout=ty.layout,
                                             inds=[i_v, m_v, zero], wraparound=False, boundscheck=False)

        def load(ptr, vec):
            return builder.load(builder.bitcast(ptr, vec.as_pointer()), align=8)

        def splat(x):
            v = builder.insert_element(ir.Constant(_V8, ir.Undefined), x, ir.Constant(i32, 0))
            return builder.shuffle_vector(v, ir.Constant(_V8, ir.Undefined), _lanes([0] * 8))

        p6 = item(j6_t, j6_a)
        k03 = load(p6, _V4)
        k45 = load(builder.gep(p6, [ir.Constant(i64, 4)]), _V2)
        with builder.if_else(aff_v) as (then, otherwise):
            with then:
                k67_aff = load(item(j2_t, j2_a), _V2)
                from_aff = builder.block
            with otherwise:
                from_none = builder.block
        k67 = builder.phi(_V2)
        k67.add_incoming(k67_aff, from_aff)
        k67.add_incoming(ir.Constant(_V2, None), from_none)
        K = builder.shuffle_vector(k03, builder.shuffle_vector(k45, k67, _lanes([0, 1, 2, 3])), _lanes(list(range(8))))
        wK = builder.fmul(splat(w_v), K)

        def add_to(offset, term):
            ptr = builder.bitcast(builder.gep(acc_a.data, [ir.Constant(i64, offset)]), _V8.as_pointer())
            builder.store(builder.fadd(builder.load(ptr, align=8), term), ptr, align=8)

        add_to(_ROWS_G, builder.fmul(wK, splat(r_v)))
        for a in range(8):
            add_to(8 * a, builder.fmul(splat(builder.extract_element(wK, ir.Constant(i32, a))), K))
        with builder.if_then(pp_v):
            add_to(_ROWS_Q, builder.fmul(wK, splat(jd_v)))
        return context.get_dummy_value()

    return sig, codegen


@jit
def _gram8(J6, J2, weight, residual, J_depth, per_point, valid):
    """The scalar sums under :func:`accumulate_pair` and :func:`target_normal_equations`: with the
    per-residual ``K = [J6, J2]`` (8 values; 6 and two zeros when ``J2`` has 0 rows),
    ``HK = sum w K K^T`` (8, 8), ``gK = sum w K r`` and, with ``per_point``, per point
    ``HpdK = sum_P w j K`` (N, 8), ``H_dd = sum_P w j^2``, ``g_d = sum_P w j r`` (``j = J_depth``;
    else those three are empty). Each residual is added by :func:`_add_residual8`, eight lanes at a
    time (the values of :func:`gram8_add`'s scalar sums, to the bit: 1.5x faster than them on
    KITTI windows). Residuals whose Jacobians are zero (invalid) add nothing whatever their weight:
    with ``valid`` (N, P) (else of 0 rows) the loop skips the residuals it flags False, whose
    residual and Jacobians are all zero (the kernels' contract): the same sums to the bit (a sum
    that starts at +0 is unchanged by adding a zero), a third less work on a KITTI window (30 %
    of its pattern pixels fall outside their target)."""
    n, p = residual.shape
    aff = J2.shape[0] == n and n > 0
    masked = valid.shape[0] == n and n > 0
    m_pt = n if per_point else 0
    HpdK = np.zeros((m_pt, 8))
    H_dd = np.zeros(m_pt)
    g_d = np.zeros(m_pt)
    acc = np.zeros(_ACC_SIZE)
    J6c = np.ascontiguousarray(J6)
    J2c = np.ascontiguousarray(J2)
    for i in range(n):
        hd = gd = 0.0
        for m in range(p):
            if masked and not valid[i, m]:
                continue
            w = weight[i, m]
            r = residual[i, m]
            jd = J_depth[i, m] if per_point else 0.0
            _add_residual8(acc, J6c, J2c, i, m, w, r, jd, aff, per_point)
            if per_point:
                hd += w * jd * jd
                gd += w * jd * r
        if per_point:
            for c in range(8):
                HpdK[i, c] = acc[_ROWS_Q + c]
                acc[_ROWS_Q + c] = 0.0
            H_dd[i] = hd
            g_d[i] = gd
    HK = np.empty((8, 8))
    for a in range(8):
        for b in range(a, 8):
            HK[a, b] = acc[8 * a + b]
            HK[b, a] = acc[8 * a + b]
    return HK, acc[_ROWS_G:_ROWS_Q].copy(), HpdK, H_dd, g_d


@jit
def accumulate_pair(J_host, J_affine_host, B, gain, weight, residual, J_depth, valid):
    """:func:`accumulate_target`'s sums (same outputs, same block order) from the host Jacobians alone.

    A photometric residual depends on the two poses only through ``T_target_host``, so its target
    pose Jacobian is its host pose Jacobian mapped by a matrix of the pair (``-Ad^-T``,
    ``J_target = J_host B^T`` with ``B = -[[R, [t]x R], [0, R]]`` of ``T_target_host = (R, t)``,
    :func:`factors.host_points.target_jacobian_map`), and its affine Jacobians are
    ``J_affine_host = (hb, gain)`` and ``J_affine_target = (-hb, -1) = -(J_affine_host[0],
    J_affine_host[1] / gain)`` (zero where invalid, as all Jacobians). So ``J = T K`` with the
    per-residual ``K = [J_host, J_affine_host]`` (8 values; without affines, ``J_affine_host`` of
    shape (0, P, 2), the 6 of ``J_host``) and a (16, 8) map ``T`` of the pair: :func:`_gram8`
    sums ``w K K^T`` (36 products per residual instead of 136), ``w K r`` and per point ``w j K``,
    then the sums are mapped by ``T``. Equal to :func:`accumulate_target` up to round-off
    (tested); ``J_target`` is not needed. ``valid``: the residuals' validity (N, P), whose False
    entries :func:`_gram8` skips (their residuals and Jacobians are zero), or an array of 0 rows.
    """
    n = residual.shape[0]
    aff = J_affine_host.shape[0] == n and n > 0
    kk = 8 if aff else 6
    HK, gK, HpdK, H_dd, g_d = _gram8(J_host, J_affine_host, weight, residual, J_depth, True, valid)
    # the map J = T K: host pose and affine (identity), target pose (B), target affine (-1, -1 / gain)
    k = 16 if aff else 12
    t_off = 8 if aff else 6
    T = np.zeros((k, kk))
    for c in range(6):
        T[c, c] = 1.0
        for j in range(6):
            T[t_off + c, j] = B[c, j]
    if aff:
        T[6, 6] = 1.0
        T[7, 7] = 1.0
        T[14, 6] = -1.0
        T[15, 7] = -1.0 / gain
    TH = T @ np.ascontiguousarray(HK[:kk, :kk])
    H = TH @ T.T
    H = 0.5 * (H + H.T)
    g = T @ np.ascontiguousarray(gK[:kk])
    H_pd = np.ascontiguousarray(HpdK[:, :kk]) @ T.T
    return H, g, H_pd, H_dd, g_d


@jit
def add_pair_terms(J_host, J_affine_host, B, gain, W, residual, J_depth, valid, k, robust, cols,
                   H, g, H_pd, H_dd, g_d, cost):
    """One host-target pair's part of ``HostPoints.linearize``, in place: each point's Huber weight
    and loss (:func:`point_huber` on ``W``), the pair's sums (:func:`accumulate_pair` with
    ``W`` times the Huber weight) added to the caller's ``H[cols, cols]``, ``g[cols]``,
    ``H_pd[:, cols]``, ``H_dd``, ``g_d``, and the losses to ``cost`` (``valid``: the residuals'
    validity, whose False entries the sums skip, :func:`_gram8`). The numpy steps it fuses
    (the weight product, the sums, five scattered additions) are the loop in
    ``HostPoints.linearize`` that linearisations without the pair's pose take; tested equal."""
    w, loss = point_huber(W, residual, k, robust)
    n, p = residual.shape
    weight = np.empty((n, p))
    for i in range(n):
        for m in range(p):
            weight[i, m] = W[i, m] * w[i]
    Ht, gt, Hpdt, Hddt, gdt = accumulate_pair(J_host, J_affine_host, B, gain, weight, residual, J_depth, valid)
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


#: the longest row :func:`pairwise_sum` sums as numpy does (numpy's pairwise block)
MAX_PAIRWISE = 128


@jit
def pairwise_sum(a, n):
    """``a[:n]`` summed as numpy sums a row (``np.sum(x, axis=-1)``: ``0.0`` plus numpy's pairwise
    summation, sequential below 8 values, eight interleaved partial sums up to
    :data:`MAX_PAIRWISE` = 128 values, beyond which numpy splits a row and this does not); the same
    result to the bit, which keeps the compiled depth terms equal to the numpy expressions."""
    if n < 8:
        res = -0.0
        for m in range(n):
            res += a[m]
        return 0.0 + res
    r0, r1, r2, r3, r4, r5, r6, r7 = a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7]
    m = 8
    while m < n - n % 8:
        r0 += a[m]
        r1 += a[m + 1]
        r2 += a[m + 2]
        r3 += a[m + 3]
        r4 += a[m + 4]
        r5 += a[m + 5]
        r6 += a[m + 6]
        r7 += a[m + 7]
        m += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while m < n:
        res += a[m]
        m += 1
    return 0.0 + res


@jit
def add_depth_terms(W, residual, J_depth, k, robust, stereo, d, prior, variance, prior_on, H_dd, g_d, cost):
    """``HostPoints.linearize``'s terms on the depths alone, in place: with ``stereo``, the stereo
    term's (``W``, ``residual``, ``J_depth`` (N, P)) Huber weights and losses (:func:`point_huber`)
    and its sums ``H_dd += sum_P wW j^2``, ``g_d += sum_P wW j r``, ``cost += loss``; then with
    ``prior_on`` the depth prior ``H_dd += 1 / V``, ``g_d += (d - prior) / V``,
    ``cost += (d - prior)^2 / (2 V)``. Returns the stereo term's Huber weights (N,) (ones without
    it). Each value is computed as the numpy expressions it replaces compute it (the same
    products, :func:`pairwise_sum` for the row sums): equal to the bit (tested) for patterns of
    at most :data:`MAX_PAIRWISE` pixels."""
    n = H_dd.shape[0]
    w = np.ones(n)
    if stereo:
        p = residual.shape[1]
        w, loss = point_huber(W, residual, k, robust)
        hd = np.empty(p)
        gd = np.empty(p)
        for i in range(n):
            for m in range(p):
                ww = W[i, m] * w[i]
                j = J_depth[i, m]
                hd[m] = ww * (j * j)
                gd[m] = (ww * j) * residual[i, m]
            H_dd[i] += pairwise_sum(hd, p)
            g_d[i] += pairwise_sum(gd, p)
            cost[i] += loss[i]
    if prior_on:
        for i in range(n):
            e = d[i] - prior[i]
            v = variance[i]
            H_dd[i] += 1.0 / v
            g_d[i] += e / v
            cost[i] += (0.5 * (e * e)) / v
    return w


@jit
def target_normal_equations(J_target, J_affine_target, weight, residual):
    """The Gauss-Newton normal equations of a frame's pose (and affine) alone, the tracker's:
    ``A = sum w J^T J``, ``b = sum w J^T r`` with ``J = [J_target, J_affine_target]`` per residual
    (8 columns; 6 without affines, ``J_affine_target`` of shape (0, P, 2)): :func:`_gram8`'s
    sums (the numpy form, concatenate, weight and two products, made four temporaries per
    evaluation). Equal to the numpy products up to round-off (tested)."""
    n = residual.shape[0]
    k = 8 if (J_affine_target.shape[0] == n and n > 0) else 6
    HK, gK, _, _, _ = _gram8(J_target, J_affine_target, weight, residual, residual, False,
                             np.zeros((0, 1), dtype=np.bool_))
    return np.ascontiguousarray(HK[:k, :k]), np.ascontiguousarray(gK[:k])
