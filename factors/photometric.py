"""Vectorised photometric residuals and their analytic Jacobians (the kernel of every factor).

For N points hosted in a host keyframe and a pixel pattern of P offsets (default
:data:`PATTERN_DSO8`), the residual of pattern pixel ``p = p_n + o_k`` in a target image is
(DSO's sign convention, used everywhere in gtvo)::

    r = I_target(w(p, d, T)) - b_t - exp(a_t - a_h) * (I_host(p) - b_h)

with the warp through the point's inverse depth ``d`` (one per point, shared by its pattern)::

    f   = K^-1 [u, v, 1]^T                   # bearing, f_z = 1
    q   = R_th f + t_th d   (= d * X_target)  # T_th = T_world_target^-1 T_world_host
    w   = (fx q_x / q_z + cx, fy q_y / q_z + cy)

Jacobians are with respect to GTSAM's right perturbations ``T <- T Exp(xi)``, ``xi = [omega, v]``
(docs/conventions.md); with ``a = dr/dq = g^T dw/dq`` (g the target gradient at w)::

    dr/dxi_target = [ a x q , -d a ]
    dr/dxi_host   = [ f x a', d a' ]     with a' = R_th^T a
    dr/dd         = a . t_th
    dr/d(a_h, b_h) = ( e (I_h - b_h), e ),  dr/d(a_t, b_t) = ( -e (I_h - b_h), -1 ),  e = exp(a_t - a_h)

Derivations with these names: docs/factors.md. Residuals that are invalid (inverse depth
<= 0, behind the target camera, outside the target image, host sample outside the host image)
are 0 with zero Jacobian rows, flagged in ``valid`` and counted; never NaN. A sample next to a
pixel the sensor clipped (:class:`GradientImage`'s ``clip_range``) is invalid too.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors import _compiled, _compiled_rows
from gtvo.core.camera import MIN_DEPTH, PinholeCamera
from gtvo.errors import InputError
from gtvo.core.lie import invert_poses

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: DSO's 8-pixel residual pattern (offsets (du, dv) in pixels of the pyramid level used).
PATTERN_DSO8: FloatArray = np.array(
    [[0, -2], [-1, -1], [1, -1], [-2, 0], [0, 0], [2, 0], [-1, 1], [0, 2]], dtype=np.float64)

#: Grey levels at or beyond which a sensor clipped, in 8-bit units: the default ``clip_range`` of
#: :class:`GradientImage` and of :class:`factors.params.PhotometricConfig` (a run sets its own there).
DEFAULT_CLIP_RANGE: tuple[float, float] = (0.0, 255.0)

#: A single pixel (no pattern), e.g. for fast coarse levels or tests.
PATTERN_SINGLE: FloatArray = np.zeros((1, 2))


class GradientSampler(Protocol):
    """An image that returns intensity and gradient at float pixel positions."""

    width: int
    height: int

    def sample(self, u: NDArray, v: NDArray) -> tuple[FloatArray, BoolArray]:
        """Return ``(values, valid)``: values ``u.shape + (3,)`` = (I, dI/du, dI/dv)."""
        ...


class GradientImage:
    """An image stacked with its central-difference gradients, sampled bilinearly.

    Args:
        image: 2-D float image in 8-bit units.
        border: pixels kept free at each side for a sample to count as valid.
        clip_range: ``(lo, hi)`` grey levels at which the sensor clipped; default
            :data:`DEFAULT_CLIP_RANGE` (0 and 255, the ends of 8-bit units). A
            sample whose bilinear cell touches a pixel at or beyond them is invalid: a clipped
            intensity says nothing about the scene's radiance, and under a brightness change (auto
            exposure) the affine model cannot explain it. None: no check.
    """

    def __init__(self, image: ArrayLike, border: float = 1.0,
                 clip_range: tuple[float, float] | None = DEFAULT_CLIP_RANGE) -> None:
        img = np.asarray(image, dtype=np.float32)
        if img.ndim != 2 or img.shape[0] < 2 or img.shape[1] < 2:
            raise InputError(f"GradientImage needs a 2-D image of at least 2x2, got shape {img.shape}")
        if clip_range is not None and (isinstance(clip_range, str) or len(clip_range) != 2):
            raise InputError(f"GradientImage: clip_range must be (lo, hi) or None, got {clip_range!r}")
        # per pixel: I, gx, gy (gtvo.core.image.image_gradients) and whether the bilinear cell with
        # this top-left corner touches a clipped pixel (1.0) or not (0.0), one 16-byte record (the
        # compiled sampler reads one cache line per corner; a separate mask array made it 3x
        # slower), made in one compiled pass. Only the intensity's cell is checked; the gradients of
        # its pixels reach one pixel further.
        lo, hi = (0.0, 0.0) if clip_range is None else clip_range
        packed, clipped, finite = _compiled.pack_gradient_image(np.ascontiguousarray(img), np.float32(lo),
                                                                np.float32(hi), clip_range is not None)
        if not finite:
            raise InputError("GradientImage: image contains NaN or infinite values")
        self.image = img
        self.height, self.width = img.shape
        self.border = float(border)
        self.clip_range = clip_range
        self.has_clipped = bool(clipped)
        self._packed = packed.reshape(-1, 4)
        #: (H, W, 3) float32: intensity and its central-difference gradients (a view)
        self.stack = packed[..., :3]

    def _sampler_args(self) -> tuple:
        """The leading arguments of :mod:`factors._compiled`'s functions for this image."""
        return (self._packed, self.has_clipped, self.width, self.height, self.border)

    def sample(self, u: NDArray, v: NDArray) -> tuple[FloatArray, BoolArray]:
        """Bilinear (I, gx, gy) at ``(u, v)``; 0 and False where invalid, never NaN.

        Same result and validity rule as :func:`gtvo.core.image.bilinear_sample` on :attr:`stack`
        up to float32 rounding of the stored image (tested to 1e-4 grey levels), in one compiled
        pass (:func:`factors._compiled.sample_stack`; the hot path of tracking). In addition, a
        sample next to a clipped pixel is invalid (``clip_range``).
        """
        u = np.asarray(u, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        if u.shape != v.shape:
            raise InputError(f"GradientImage.sample: u has shape {u.shape}, v {v.shape}")
        values, valid = _compiled.sample_stack(*self._sampler_args(), np.ascontiguousarray(u).reshape(-1),
                                               np.ascontiguousarray(v).reshape(-1))
        return values.reshape(u.shape + (3,)), valid.reshape(u.shape)


def _relative_pose(T_world_a: object, T_world_b: object) -> FloatArray:
    """``T_a_b = T_world_a^-1 T_world_b`` as a 4x4 matrix (``gtsam.Pose3`` or 4x4 inputs).

    Rigid inverse (``R^T``), not a general solve: the per-call cost of the window's many small
    kernel calls (a 4x4 ``np.linalg.solve`` took as long as a tenth of a 300-point kernel call).
    """
    if hasattr(T_world_a, "between") and hasattr(T_world_b, "matrix"):
        return np.asarray(T_world_a.between(T_world_b).matrix(), dtype=float)  # type: ignore[attr-defined]
    return invert_poses(_as_matrix(T_world_a)) @ _as_matrix(T_world_b)


def pair_pose(T_world_host: object, T_world_target: object) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``T_target_host`` of a host-target pair as the compiled loops take it: ``(T (4, 4), R (3, 3),
    t (3,))``, C-contiguous, the values :func:`compiled_residuals` computes (:func:`_relative_pose`).
    The passes at one state share them: not to be modified."""
    T = _relative_pose(T_world_target, T_world_host)
    return T, T[:3, :3].copy(), T[:3, 3].copy()


def stereo_pair_pose(baseline: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`pair_pose` of :func:`stereo_residuals`' warp (host: the left camera at the origin,
    target: the right one at ``+baseline`` along its x axis), the same values."""
    T_world_right = np.eye(4)
    T_world_right[0, 3] = float(baseline)
    return pair_pose(np.eye(4), T_world_right)


def _as_matrix(T: object) -> FloatArray:
    """A 4x4 matrix from a ``gtsam.Pose3`` or an array."""
    if hasattr(T, "matrix"):
        return np.asarray(T.matrix(), dtype=float)  # type: ignore[attr-defined]
    M = np.asarray(T, dtype=float)
    if M.shape != (4, 4):
        raise InputError(f"pose must be a 4x4 matrix or gtsam.Pose3, got shape {M.shape}")
    return M


def pattern_pixels(pixels: ArrayLike, pattern: ArrayLike = PATTERN_DSO8) -> FloatArray:
    """Pixels of every pattern offset around every point: shape (N, P, 2)."""
    px = np.asarray(pixels, dtype=float).reshape(-1, 1, 2)
    pat = np.asarray(pattern, dtype=float).reshape(1, -1, 2)
    return px + pat


def pattern_bearings(camera: PinholeCamera, pixels: ArrayLike, pattern: ArrayLike = PATTERN_DSO8) -> FloatArray:
    """Bearings ``f = K^-1 [u, v, 1]`` (f_z = 1) of every pattern pixel: shape (N, P, 3)."""
    pp = pattern_pixels(pixels, pattern)
    f = np.empty(pp.shape[:2] + (3,))
    f[..., 0] = (pp[..., 0] - camera.cx) / camera.fx
    f[..., 1] = (pp[..., 1] - camera.cy) / camera.fy
    f[..., 2] = 1.0
    return f


def _cross_into(out: FloatArray, a: FloatArray, b: FloatArray) -> None:
    """``out[..., :3] = a x b`` without np.cross's axis shuffling."""
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def sample_host(host: GradientSampler, pixels: ArrayLike,
                pattern: ArrayLike = PATTERN_DSO8) -> tuple[FloatArray, BoolArray]:
    """Host intensities at the pattern around each point: ``(I_host (N, P), valid (N, P))``.

    The host values do not depend on any variable, so they are sampled once per point.
    """
    pp = pattern_pixels(pixels, pattern)
    vals, ok = host.sample(pp[..., 0], pp[..., 1])
    return vals[..., 0], ok


@dataclass
class PhotometricLinearization:
    """Residuals and Jacobians of N points x P pattern pixels in one target.

    All arrays are zero where ``valid`` is False. Pose Jacobians are 6-vectors in GTSAM's
    [rotation, translation] order for right perturbations.
    """

    residual: FloatArray  #: (N, P) r = I_t(w) - b_t - exp(a_t - a_h)(I_h - b_h)
    valid: BoolArray  #: (N, P)
    J_depth: FloatArray  #: (N, P) dr/dd
    J_host: FloatArray | None  #: (N, P, 6) dr/dxi_host
    J_target: FloatArray | None  #: (N, P, 6) dr/dxi_target
    J_affine_host: FloatArray | None  #: (N, P, 2) dr/d(a_h, b_h)
    J_affine_target: FloatArray | None  #: (N, P, 2) dr/d(a_t, b_t)
    uv_target: FloatArray  #: (N, P, 2) warped pixels (meaningless where invalid)
    n_bad_depth: int  #: points with inverse depth <= 0 (or not finite)
    n_behind: int  #: pattern pixels behind the target camera (of points with good depth)
    #: pattern pixels outside the target or host image or next to a clipped pixel (in front, good depth)
    n_outside: int
    #: (N, P, 2) dr/d(delta_x, delta_y) of a stereo residual's rig offset (:func:`stereo_residuals`
    #: with ``offset_jacobians``), else None
    J_offset: FloatArray | None = None
    #: (4, 4) ``T_target_host`` the residuals were evaluated at, and the brightness gain
    #: ``exp(a_t - a_h)``: with them the Gauss-Newton sums need only the host Jacobians
    #: (:func:`factors.host_points.gauss_newton_sums`)
    T_target_host: FloatArray | None = None
    brightness_gain: float | None = None

    @property
    def has_pair_pose(self) -> bool:
        """``T_target_host`` and the gain are known: the target's Jacobians follow from the host's."""
        return self.T_target_host is not None and self.brightness_gain is not None


def put_rows(lin: PhotometricLinearization, rows: NDArray[np.intp], other: PhotometricLinearization,
             other_rows: NDArray[np.intp] | None = None) -> PhotometricLinearization:
    """Overwrite ``lin``'s points ``rows`` with ``other``'s points ``other_rows`` (default: all of
    them, in order), in place: the same points evaluated elsewhere, e.g. at other inverse depths.
    The counters (``n_bad_depth``, ...) stay ``lin``'s. The pair's ``T_target_host`` and gain stay
    only when ``other`` was evaluated at the same ones (else they are cleared: the rows no longer
    share one pair pose, and the Gauss-Newton sums then need the target Jacobians). Returns ``lin``."""
    sel = slice(None) if other_rows is None else other_rows
    dst = np.ascontiguousarray(rows, dtype=np.intp)
    src = np.arange(dst.size, dtype=np.intp) if other_rows is None else np.ascontiguousarray(other_rows, dtype=np.intp)
    n, m = lin.residual.shape[0], other.residual.shape[0]
    # one compiled loop per array (numpy's gather and scatter took about 5x its time) for indices in range
    compiled = dst.size == src.size and (dst.size == 0 or (0 <= dst.min() and dst.max() < n and 0 <= src.min()
                                                            and src.max() < m))
    for name in ("residual", "valid", "J_depth", "J_host", "J_target", "J_affine_host", "J_affine_target",
                 "uv_target", "J_offset"):
        a, b = getattr(lin, name), getattr(other, name)
        if a is not None and b is not None:
            if (compiled and a.dtype == b.dtype and a.shape[0] == n and b.shape[0] == m and a.shape[1:] == b.shape[1:]
                    and a.flags.c_contiguous and b.flags.c_contiguous):
                k = math.prod(a.shape[1:])
                _compiled_rows.copy_rows(a.reshape(1, n, k), dst, b.reshape(1, m, k), src)
            else:
                a[rows] = b[sel]
        elif a is not None:  # nothing to copy from: the array no longer describes every point
            setattr(lin, name, None)
    if lin.T_target_host is not None and not (
            other.T_target_host is not None and np.array_equal(lin.T_target_host, other.T_target_host)
            and lin.brightness_gain == other.brightness_gain):
        lin.T_target_host = lin.brightness_gain = None
    return lin


def compiled_residuals(camera: PinholeCamera, host_intensity: FloatArray, host_valid: NDArray[np.bool_],
                       bearings: FloatArray, inverse_depth: FloatArray, T_world_host: object,
                       T_world_target: object, target: GradientImage, log_gain: float, b_host: float, b_target: float,
                       jacobians: bool = True, host_jacobians: bool = True,
                       target_jacobians: bool = True) -> PhotometricLinearization:
    """:func:`photometric_residuals` for a :class:`GradientImage` target on arguments already checked
    and laid out (C-contiguous float64 ``(N, P)`` intensities, bool validity, ``(N, P, 3)``
    bearings, ``(N,)`` inverse depths; poses as there; ``log_gain = a_t - a_h``): the
    compiled loops without the per-call checks, for callers that evaluate the same points many
    times (:class:`factors.host_points.HostPoints`). ``target_jacobians=False`` leaves ``J_target`` and
    ``J_affine_target`` out (None): the window's Gauss-Newton sums map them from the host
    Jacobians (:func:`factors.host_points.gauss_newton_sums`)."""
    T_target_host, R, t = pair_pose(T_world_host, T_world_target)
    gain = float(np.exp(log_gain))
    r, valid, J_depth, uv, J_t, J_h, J_at, J_ah, counts = _compiled.warp_residuals(
        *target._sampler_args(), float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy),
        float(MIN_DEPTH), R, t, bearings, inverse_depth, host_intensity, host_valid, gain, float(b_host),
        float(b_target), bool(jacobians), bool(host_jacobians), bool(target_jacobians))
    n_bad, n_behind, n_out = counts.tolist()
    if not jacobians:
        return PhotometricLinearization(r, valid, J_depth, None, None, None, None, uv, n_bad, n_behind, n_out)
    if not host_jacobians:
        J_h = J_ah = None
    if not target_jacobians:
        J_t = J_at = None
    return PhotometricLinearization(r, valid, J_depth, J_h, J_t, J_ah, J_at, uv, n_bad, n_behind, n_out,
                                    T_target_host=T_target_host, brightness_gain=gain)


def photometric_residuals(camera: PinholeCamera, host_intensity: ArrayLike, host_valid: ArrayLike | None,
                          pixels: ArrayLike, inverse_depth: ArrayLike, T_world_host: object,
                          T_world_target: object, target: GradientSampler,
                          affine_host: ArrayLike = (0.0, 0.0), affine_target: ArrayLike = (0.0, 0.0),
                          pattern: ArrayLike = PATTERN_DSO8, jacobians: bool = True,
                          host_jacobians: bool = True, bearings: ArrayLike | None = None) -> PhotometricLinearization:
    """Photometric residuals of hosted points in one target image, with analytic Jacobians.

    A :class:`GradientImage` target runs the compiled loops of :mod:`factors._compiled`; any other
    :class:`GradientSampler` runs the numpy form below. Both give the same outputs (tested).

    Args:
        camera: intrinsics of the pyramid level (host and target share them).
        host_intensity: (N, P) host intensities at the pattern (:func:`sample_host`).
        host_valid: (N, P) validity of those samples, or None (all valid).
        pixels: (N, 2) host pixels of the points at this level.
        inverse_depth: (N,) inverse depths ``d = 1/z`` in the host camera.
        T_world_host, T_world_target: poses (``gtsam.Pose3`` or 4x4).
        target: the target image with gradients.
        affine_host, affine_target: brightness parameters ``(a, b)``.
        pattern: (P, 2) pixel offsets.
        jacobians: compute Jacobians (False: residuals, masks and dr/dd only).
        host_jacobians: also compute ``J_host`` and ``J_affine_host`` (False: they are None;
            tracking with a fixed keyframe does not need them).
        bearings: (N, P, 3) precomputed :func:`pattern_bearings` (they depend on the host pixels
            only; a tracker computes them once per keyframe and level).
    """
    pat = np.asarray(pattern, dtype=float).reshape(-1, 2)
    px = np.asarray(pixels, dtype=float).reshape(-1, 2)
    d = np.asarray(inverse_depth, dtype=float).reshape(-1)
    n, p = px.shape[0], pat.shape[0]
    if d.shape[0] != n:
        raise InputError(f"photometric_residuals: {n} pixels but {d.shape[0]} inverse depths")
    Ih = np.asarray(host_intensity, dtype=float).reshape(n, p)
    hv = np.ones((n, p), dtype=bool) if host_valid is None else np.asarray(host_valid, dtype=bool).reshape(n, p)
    Tth = _relative_pose(T_world_target, T_world_host)
    R = Tth[:3, :3]
    t = Tth[:3, 3]
    a_h, b_h = (float(x) for x in np.asarray(affine_host, dtype=float).reshape(2))
    a_t, b_t = (float(x) for x in np.asarray(affine_target, dtype=float).reshape(2))

    f = pattern_bearings(camera, px, pat) if bearings is None else np.asarray(bearings, dtype=float)
    if f.size != n * p * 3:
        raise InputError(f"photometric_residuals: bearings have shape {f.shape}, expected {(n, p, 3)}")
    f = f.reshape(n, p, 3)
    if isinstance(target, GradientImage):
        # the compiled loops (same outputs as the numpy form below, which other samplers take)
        return compiled_residuals(camera, np.ascontiguousarray(Ih), np.ascontiguousarray(hv), np.ascontiguousarray(f),
                                  np.ascontiguousarray(d), T_world_host, T_world_target, target, a_t - a_h, b_h, b_t,
                                  jacobians, host_jacobians)

    good_d = np.isfinite(d) & (d > 0)
    ds = np.where(good_d, d, 1.0)
    # (N*P, 3) products: numpy runs (N, P, 3) @ (3, 3) as N small products, 2.5-5x slower
    q = (f.reshape(-1, 3) @ R.T).reshape(n, p, 3) + ds[:, None, None] * t
    qz = q[..., 2]
    front = qz > MIN_DEPTH * ds[:, None]
    qzs = np.where(front, qz, 1.0)
    iz = 1.0 / qzs
    uv = np.empty((n, p, 2))
    uv[..., 0] = camera.fx * q[..., 0] * iz + camera.cx
    uv[..., 1] = camera.fy * q[..., 1] * iz + camera.cy
    vals, inside = target.sample(uv[..., 0], uv[..., 1])
    valid = good_d[:, None] & front & inside & hv
    e = np.exp(a_t - a_h)
    r = vals[..., 0] - b_t - e * (Ih - b_h)
    r = np.where(valid, r, 0.0)

    n_bad = int(np.count_nonzero(~good_d))
    n_behind = int(np.count_nonzero(good_d[:, None] & ~front))
    n_out = int(np.count_nonzero(good_d[:, None] & front & ~(inside & hv)))

    gx = np.where(valid, vals[..., 1], 0.0)
    gy = np.where(valid, vals[..., 2], 0.0)
    # a = dr/dq = g^T dw/dq, dw/dq = [[fx/qz, 0, -fx qx/qz^2], [0, fy/qz, -fy qy/qz^2]]
    a = np.empty((n, p, 3))
    a[..., 0] = gx * camera.fx * iz
    a[..., 1] = gy * camera.fy * iz
    a[..., 2] = -(a[..., 0] * q[..., 0] + a[..., 1] * q[..., 1]) * iz
    J_depth = (a.reshape(-1, 3) @ t).reshape(n, p)
    if not jacobians:
        return PhotometricLinearization(r, valid, J_depth, None, None, None, None, uv, n_bad, n_behind, n_out)
    dd = ds[:, None, None]
    J_target = np.empty((n, p, 6))
    _cross_into(J_target, a, q)
    J_target[..., 3:] = -dd * a
    hb = np.where(valid, e * (Ih - b_h), 0.0)
    vf = valid.astype(float)
    J_aff_t = np.stack([-hb, -vf], axis=-1)
    J_host = J_aff_h = None
    if host_jacobians:
        ap = (a.reshape(-1, 3) @ R).reshape(n, p, 3)  # R^T a, row form
        J_host = np.empty((n, p, 6))
        _cross_into(J_host, f, ap)
        J_host[..., 3:] = dd * ap
        J_aff_h = np.stack([hb, e * vf], axis=-1)
    return PhotometricLinearization(r, valid, J_depth, J_host, J_target, J_aff_h, J_aff_t, uv,
                                    n_bad, n_behind, n_out, T_target_host=Tth, brightness_gain=float(e))


@functools.lru_cache(maxsize=16)
def _offset_projection(camera: PinholeCamera, dx: float, dy: float) -> PinholeCamera:
    """``camera`` with its principal point moved by ``(dx, dy)``: made (and checked) once per offset,
    not at every stereo evaluation of an optimisation that holds the offset."""
    return dataclasses.replace(camera, cx=camera.cx + dx, cy=camera.cy + dy)


def stereo_residuals(camera: PinholeCamera, baseline: float, left_intensity: ArrayLike,
                     left_valid: ArrayLike | None, pixels: ArrayLike, inverse_depth: ArrayLike,
                     right: GradientSampler, affine_left: ArrayLike = (0.0, 0.0),
                     affine_right: ArrayLike = (0.0, 0.0),
                     pattern: ArrayLike = PATTERN_DSO8, jacobians: bool = True,
                     bearings: ArrayLike | None = None, offset: ArrayLike | None = None,
                     offset_jacobians: bool = False) -> PhotometricLinearization:
    """Left-right residual of points of a rectified stereo frame.

    ``p' = d^R K T_RL (d^L)^-1 K^-1 p`` with ``T_RL`` a translation ``(-b, 0, 0)``: the right
    pixel is ``(u - fx b d, v)``, so ``dp'/dd = (-fx b, 0)`` (not zero) and
    ``dr/dd = -fx b gx_R``. Returned as a :class:`PhotometricLinearization` whose "host" is
    the left image and "target" the right image (pose Jacobians are None).
    ``jacobians=False``: residuals, masks and ``J_depth`` only (affine Jacobians None too);
    ``bearings``: precomputed :func:`pattern_bearings` of the left pixels.

    ``offset``: the rig's rectification error ``(delta_x, delta_y)`` (px): the right image is
    sampled at ``(u - fx b d + delta_x, v + delta_y)`` (a right image shifted right by ``s`` px
    has ``delta_x = s``; docs/factors.md §5). None or zero: the rectified model above.
    ``offset_jacobians``: also return ``J_offset = dr/d(delta_x, delta_y) = (gx_R, gy_R)``, the right
    image's gradient at the match (the residual's right intensity carries no gain: the stereo
    affine multiplies the left one).
    """
    T_world_right = np.eye(4)
    T_world_right[0, 3] = float(baseline)  # right camera at +b along the left x axis
    projection = camera
    if offset is not None:
        dx, dy = (float(x) for x in np.asarray(offset, dtype=float).reshape(2))
        if not (np.isfinite(dx) and np.isfinite(dy)):
            raise InputError(f"stereo_residuals: rig offset must be finite, got {(dx, dy)!r}")
        if dx != 0.0 or dy != 0.0:
            if bearings is None:  # the bearings are the left camera's; only the projection moves
                bearings = pattern_bearings(camera, pixels, pattern)
            # the warp's q_z is 1 (no rotation, no z translation): shifting the principal point
            # shifts the sampled right pixel by exactly (delta_x, delta_y)
            projection = _offset_projection(camera, dx, dy)
    lin = photometric_residuals(projection, left_intensity, left_valid, pixels, inverse_depth, np.eye(4),
                                T_world_right, right, affine_left, affine_right, pattern, jacobians=jacobians,
                                host_jacobians=jacobians, bearings=bearings)
    if offset_jacobians:
        # the warp's q_z is 1, so dr/d(delta_x, delta_y) is the right image's gradient at the sampled
        # pixel itself: one more bilinear sample of the gradients, not the pose Jacobians
        vals, _ = right.sample(lin.uv_target[..., 0], lin.uv_target[..., 1])
        lin.J_offset = np.where(lin.valid[..., None], vals[..., 1:3], 0.0)
    if not jacobians:
        lin.J_affine_host = lin.J_affine_target = None
    lin.J_host = None
    lin.J_target = None
    return lin
