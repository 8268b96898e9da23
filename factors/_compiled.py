"""Compiled loops (numba) for the hot path of :mod:`factors.photometric`.

Each is the loop form of vectorised numpy code that stays the reference (tests compare them to it,
and to numerical derivatives through it):

* :func:`sample_stack`: :meth:`GradientImage.sample` (bilinear intensity and gradients, the
  border and clipped-cell validity rule);
* :func:`warp_residuals`: :func:`photometric_residuals` for a :class:`GradientImage` target in
  three tight loops (warp, gather, residuals and Jacobians) instead of about 40 numpy passes;
* :func:`pack_gradient_image`: ``GradientImage``'s record array (intensity, central-difference
  gradients as ``gtvo.core.image.image_gradients``, clipped-cell flag) in one pass over the image;
(The window's Gauss-Newton sums and Huber terms: :mod:`factors._compiled_sums`.)

Why compiled: the numpy form makes about 40 passes over (N, P) arrays per call, each a
temporary array, and the kernel was about half of a whole VO run (docs/benchmarks.md, "Compiled
photometric kernel"). The arithmetic here is float64 throughout (the numpy sampler it replaced
interpolated in float32: results moved by about 1e-5 grey levels, the KITTI figures not at all).

Compiled on first use and cached on disk (:func:`gtvo.core.jit.jit`).
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from gtvo.core.jit import jit


@intrinsic
def _prefetch_record(typingctx, records, index):
    """Ask the CPU to start loading record ``index`` of a (M, 4) record array into its caches (LLVM's
    ``prefetch``: a hint, no result, no fault, whatever the index): the gathers that follow find
    their cache lines on the way instead of waiting for each miss in turn."""
    sig = types.void(records, index)

    def codegen(context, builder, signature, args):
        rec_type = signature.args[0]
        rec = context.make_array(rec_type)(context, builder, args[0])
        ptr = cgutils.get_item_pointer2(context, builder, data=rec.data, shape=cgutils.unpack_tuple(builder, rec.shape),
                                        strides=cgutils.unpack_tuple(builder, rec.strides), layout=rec_type.layout,
                                        inds=[args[1], context.get_constant(types.intp, 0)], wraparound=False,
                                        boundscheck=False)
        byte_ptr = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [byte_ptr, i32, i32, i32]),
                                            "llvm.prefetch.p0i8")
        # read (0), keep in all cache levels (3), data (1)
        builder.call(fn, [builder.bitcast(ptr, byte_ptr), ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _prefetch_row_for_write(typingctx, arr, index):
    """Ask the CPU to fetch row ``index`` of ``arr`` (along its first axis, a contiguous block of
    ``strides[0]`` bytes) into its caches for writing (LLVM's ``prefetch`` with the write hint, one
    per cache line the row touches): a hint, no result, no fault. The pass's output rows are
    rarely still cached (a host's buffers are a few MB), and each store that misses waits for its
    line to be read first."""
    sig = types.void(arr, index)

    def codegen(context, builder, signature, args):
        a = context.make_array(signature.args[0])(context, builder, args[0])
        row_bytes = cgutils.unpack_tuple(builder, a.strides)[0]
        byte_ptr = ir.IntType(8).as_pointer()
        base = builder.gep(builder.bitcast(a.data, byte_ptr), [builder.mul(args[1], row_bytes)])
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [byte_ptr, i32, i32, i32]),
                                            "llvm.prefetch.p0i8")
        # write (1), keep in all cache levels (3), data (1)
        hint = [ir.Constant(i32, 1), ir.Constant(i32, 3), ir.Constant(i32, 1)]
        line = context.get_constant(types.intp, 64)
        with cgutils.for_range_slice(builder, context.get_constant(types.intp, 0), row_bytes, line) as (offset, _):
            builder.call(fn, [builder.gep(base, [offset])] + hint)
        # the row's last byte: its line when the row does not start on a line
        last = builder.sub(row_bytes, context.get_constant(types.intp, 1))
        builder.call(fn, [builder.gep(base, [last])] + hint)
        return context.get_dummy_value()

    return sig, codegen


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

    The loops of :func:`warp_into`, into arrays allocated here.

    Returns:
        ``(r, valid, J_depth, uv, J_target, J_host, J_affine_target, J_affine_host, counts)``;
        the Jacobian arrays have 0 rows when not asked for (``jacobians`` False: none;
        ``host_jacobians`` / ``target_jacobians`` False: not those); ``counts`` = (n_bad_depth,
        n_behind, n_outside).
    """
    n, p = host_intensity.shape
    r = np.empty((n, p))
    valid = np.empty((n, p), dtype=np.bool_)
    J_depth = np.empty((n, p))
    uv = np.empty((n, p, 2))
    nj = n if (jacobians and target_jacobians) else 0
    nh = n if (jacobians and host_jacobians) else 0
    J_target = np.empty((nj, p, 6))
    J_aff_t = np.empty((nj, p, 2))
    J_host = np.empty((nh, p, 6))
    J_aff_h = np.empty((nh, p, 2))
    counts = np.zeros(3, dtype=np.int64)
    warp_into(packed, has_clip, width, height, border, fx, fy, cx, cy, min_depth, R, t, f, d, host_intensity,
              host_valid, np.arange(n), e, b_h, b_t, jacobians, host_jacobians, target_jacobians, False,
              r, valid, J_depth, uv, J_target, J_host, J_aff_t, J_aff_h, np.empty((0, p, 2)), counts)
    return r, valid, J_depth, uv, J_target, J_host, J_aff_t, J_aff_h, counts


@jit
def warp_into(packed, has_clip, width, height, border, fx, fy, cx, cy, min_depth, R, t, f, d,
              host_intensity, host_valid, rows, e, b_h, b_t, jacobians, host_jacobians, target_jacobians,
              offset_jacobians, r, valid, J_depth, uv, J_target, J_host, J_aff_t, J_aff_h, J_offset, counts):
    """:func:`warp_residuals`' loops for the points ``rows`` (indices into ``f``, ``d``,
    ``host_intensity``, ``host_valid``, read in place: no gathered copies), written into the given
    outputs: row ``i`` of ``r``, ``valid``, ``J_depth``, ``uv`` (M, P[, 2]) and of the Jacobians
    (M, P, 6 or 2; 0 rows when not asked for, as :func:`warp_residuals` makes them) is point
    ``rows[i]``; every entry is written (zeros where not valid), so the outputs may be reused
    buffers. ``offset_jacobians``: also ``J_offset`` (M, P, 2), the target's gradient at the
    sampled pixel (``dr/d(delta_x, delta_y)`` of a stereo residual's rig offset,
    :func:`factors.photometric.stereo_residuals`). ``counts`` (3,) are incremented.

    Three loops over the residuals: warp (arithmetic, and a prefetch of the four records each sample
    will read: the window's images do not fit the cache, and the gathers took about half of a pass
    waiting for them; the prefetches took 15-35 % off a call, and those of the cell's right column,
    whose pair of records crosses a cache line one time in four, another 5 %), gather (the bilinear samples;
    a short loop body lets the CPU keep many cache misses in flight, 1.5x faster than one fused
    loop on KITTI images; it also prefetches, for writing, the next point's rows of the outputs:
    10 % off a call), then residuals and Jacobians.
    """
    n = rows.shape[0]
    p = host_intensity.shape[1]
    R00, R01, R02 = R[0, 0], R[0, 1], R[0, 2]
    R10, R11, R12 = R[1, 0], R[1, 1], R[1, 2]
    R20, R21, R22 = R[2, 0], R[2, 1], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    target_j = jacobians and target_jacobians
    host_j = jacobians and host_jacobians
    # phase A: warp every residual (arithmetic only)
    q = np.empty((n, p, 3))
    izs = np.empty((n, p))
    d_safe = np.ones(n)  # the inverse depth, 1 where it is not usable
    state = np.zeros((n, p), dtype=np.int8)  # 0 bad depth, 1 behind, 2 in front
    for i in range(n):
        src = rows[i]
        di = d[src]
        good = np.isfinite(di) and di > 0.0
        if good:
            d_safe[i] = di
        else:
            counts[0] += 1
        ds = d_safe[i]
        for k in range(p):
            f0, f1, f2 = f[src, k, 0], f[src, k, 1], f[src, k, 2]
            q0 = R00 * f0 + R01 * f1 + R02 * f2 + ds * t0
            q1 = R10 * f0 + R11 * f1 + R12 * f2 + ds * t1
            q2 = R20 * f0 + R21 * f1 + R22 * f2 + ds * t2
            front = q2 > min_depth * ds
            iz = 1.0 / q2 if front else 1.0
            q[i, k, 0] = q0
            q[i, k, 1] = q1
            q[i, k, 2] = q2
            izs[i, k] = iz
            u = fx * q0 * iz + cx
            v = fy * q1 * iz + cy
            uv[i, k, 0] = u
            uv[i, k, 1] = v
            if good:
                if front:
                    state[i, k] = 2
                else:
                    state[i, k] = 1
                    counts[1] += 1
            if u >= 0.0 and v >= 0.0 and u < width - 1 and v < height - 1:  # the cell's four records
                cell = int(v) * width + int(u)
                _prefetch_record(packed, cell)
                _prefetch_record(packed, cell + 1)
                _prefetch_record(packed, cell + width)
                _prefetch_record(packed, cell + width + 1)
    # phase B: gather (a tight loop: many loads in flight), only what can become a residual
    S = np.empty((n, p, 3))
    inside = np.zeros((n, p), dtype=np.bool_)
    for i in range(n):
        src = rows[i]
        if i + 1 < n:  # the next point's output rows, which phase C writes: in the caches by then
            _prefetch_row_for_write(r, i + 1)
            _prefetch_row_for_write(J_depth, i + 1)
            if host_j:
                _prefetch_row_for_write(J_host, i + 1)
                _prefetch_row_for_write(J_aff_h, i + 1)
            if target_j:
                _prefetch_row_for_write(J_target, i + 1)
                _prefetch_row_for_write(J_aff_t, i + 1)
        for k in range(p):
            if state[i, k] == 2 and host_valid[src, k]:
                ok, intensity, gx, gy = _bilinear(packed, has_clip, width, height, border, uv[i, k, 0], uv[i, k, 1])
                inside[i, k] = ok
                S[i, k, 0] = intensity
                S[i, k, 1] = gx
                S[i, k, 2] = gy
    # phase C: residuals and Jacobians
    for i in range(n):
        ds = d_safe[i]
        src = rows[i]
        for k in range(p):
            ok = state[i, k] == 2
            if ok and not (inside[i, k] and host_valid[src, k]):
                counts[2] += 1
                ok = False
            if not ok:  # an invalid residual: zeros
                r[i, k] = 0.0
                valid[i, k] = False
                J_depth[i, k] = 0.0
                if target_j:
                    for m in range(6):
                        J_target[i, k, m] = 0.0
                    J_aff_t[i, k, 0] = 0.0
                    J_aff_t[i, k, 1] = 0.0
                if host_j:
                    for m in range(6):
                        J_host[i, k, m] = 0.0
                    J_aff_h[i, k, 0] = 0.0
                    J_aff_h[i, k, 1] = 0.0
                if offset_jacobians:
                    J_offset[i, k, 0] = 0.0
                    J_offset[i, k, 1] = 0.0
                continue
            f0, f1, f2 = f[src, k, 0], f[src, k, 1], f[src, k, 2]
            q0, q1, q2 = q[i, k, 0], q[i, k, 1], q[i, k, 2]
            iz = izs[i, k]
            intensity, gx, gy = S[i, k, 0], S[i, k, 1], S[i, k, 2]
            valid[i, k] = True
            hb = e * (host_intensity[src, k] - b_h)
            r[i, k] = intensity - b_t - hb
            # a = dr/dq = g^T dw/dq
            a0 = gx * fx * iz
            a1 = gy * fy * iz
            a2 = -(a0 * q0 + a1 * q1) * iz
            J_depth[i, k] = a0 * t0 + a1 * t1 + a2 * t2
            if offset_jacobians:
                J_offset[i, k, 0] = gx
                J_offset[i, k, 1] = gy
            if target_j:
                J_target[i, k, 0] = a1 * q2 - a2 * q1
                J_target[i, k, 1] = a2 * q0 - a0 * q2
                J_target[i, k, 2] = a0 * q1 - a1 * q0
                J_target[i, k, 3] = -ds * a0
                J_target[i, k, 4] = -ds * a1
                J_target[i, k, 5] = -ds * a2
                J_aff_t[i, k, 0] = -hb
                J_aff_t[i, k, 1] = -1.0
            if host_j:
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


def pack_gradient_image(img: np.ndarray, lo: np.float32, hi: np.float32, check_clip: bool
                        ) -> tuple[np.ndarray, bool, bool]:
    """``GradientImage``'s packed records of a (H, W) float32 image (H, W >= 2): per pixel the
    intensity, ``image_gradients``' central differences (one-sided at the borders, the same float32
    arithmetic) and, with ``check_clip``, 1.0 where the bilinear cell with this top-left corner
    touches a pixel at or beyond ``lo`` / ``hi``. Returns ``(packed (H, W, 4), any pixel clipped,
    all finite)``, written by :func:`pack_gradient_records`.

    The records are allocated by numpy, not inside the compiled loop: numpy asks the kernel for
    transparent huge pages (``madvise``) for arrays of 4 MB and more, numba's allocator does not.
    A residual pass samples a few pixels in each of many rows, and a KITTI row of records is 20 kB,
    so with 4 kB pages nearly every bilinear sample missed the TLB (a page walk, dearer in a virtual
    machine); with 2 MB pages the warp kernels' gathers took about half the time (docs/window.md,
    "Cost of an optimisation").
    """
    h, w = img.shape
    packed = np.empty((h, w, 4), dtype=np.float32)
    clipped_any, finite = pack_gradient_records(img, lo, hi, check_clip, packed)
    return packed, bool(clipped_any), bool(finite)


@jit
def pack_gradient_records(img, lo, hi, check_clip, packed):
    """:func:`pack_gradient_image`'s loop: writes the records of ``img`` into ``packed`` (H, W, 4)
    float32; returns ``(any pixel clipped, all finite)``.

    Row by row: the two border columns (one-sided differences), then the interior ones without a
    branch (1.6x faster than one loop with the border tests in it), then the row's clipped pixels
    and finiteness without a branch (a NaN or an infinity leaves ``c - c`` not 0); a cell's flag is
    written once its lower row's clipped pixels are known: the or of its four corners' (a row of
    bytes kept for the row above). 1.2x faster than flagging the cells of each clipped pixel as
    it was met, on KITTI images (whose sky is clipped)."""
    h, w = img.shape
    half = np.float32(0.5)
    zero = np.float32(0.0)
    finite = True
    clipped_any = False
    above = np.zeros(w, dtype=np.uint8)  # the row above's clipped pixels (1), and this row's
    this = np.zeros(w, dtype=np.uint8)
    for y in range(h):
        ym = y - 1 if y > 0 else 0
        yp = y + 1 if y < h - 1 else h - 1
        fy = half if 0 < y < h - 1 else np.float32(1.0)  # 1 * difference: the one-sided one, exactly
        row = img[y]
        up = img[ym]
        down = img[yp]
        out = packed[y]
        for x in (0, w - 1):
            xm = x - 1 if x > 0 else 0
            xp = x + 1 if x < w - 1 else w - 1
            out[x, 0] = row[x]
            out[x, 1] = row[xp] - row[xm]
            out[x, 2] = fy * (down[x] - up[x])
            out[x, 3] = zero
        for x in range(1, w - 1):
            out[x, 0] = row[x]
            out[x, 1] = half * (row[x + 1] - row[x - 1])
            out[x, 2] = fy * (down[x] - up[x])
            out[x, 3] = zero
        bad = np.uint8(0)
        n_clipped = 0
        for x in range(w):
            c = row[x]
            bad |= np.uint8(not (c - c == zero))
            k = np.uint8((c <= lo) | (c >= hi))
            this[x] = k
            n_clipped += k
        if bad:
            finite = False
        if check_clip:
            if n_clipped:
                clipped_any = True
            if y > 0:
                cells = packed[y - 1]
                for x in range(w - 1):
                    cells[x, 3] = np.float32(above[x] | above[x + 1] | this[x] | this[x + 1])
        above, this = this, above
    return clipped_any, finite


@jit
def stacked_point_losses(weight, residual, rows, k, robust, d, prior, variance, depth_prior):
    """Each point's summed Huber loss over a host's T1 residual terms (its targets, then its stereo
    term): ``weight`` (T1, N, P) of all N points, ``residual`` (T1, M, P) of the points ``rows``
    (M,); per point the terms' losses added in order, each that of
    :func:`factors._compiled_sums.point_huber` (the same arithmetic, so the same values), then with
    ``depth_prior`` the prior's ``0.5 (d - prior)^2 / variance`` (``d``, ``prior``, ``variance``
    (N,)), as ``HostPoints.point_costs`` adds it.
    """
    nt, m, p = residual.shape
    out = np.empty(m)
    for i in range(m):
        src = rows[i]
        c = 0.0
        for t in range(nt):
            s = 0.0
            for j in range(p):
                s += weight[t, src, j] * residual[t, i, j] * residual[t, i, j]
            x = np.sqrt(s)
            if not robust or x <= k:
                c += 0.5 * x * x
            else:
                c += k * x - 0.5 * k * k
        if depth_prior:
            x = d[src] - prior[src]
            c += 0.5 * (x * x) / variance[src]
        out[i] = c
    return out
