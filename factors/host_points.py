"""The points hosted in one keyframe, linearised with their inverse depths eliminated (numpy and the
compiled sums of :mod:`factors._compiled_sums`; no GTSAM).

:class:`HostPoints` is the per-host core of both window solvers: the GTSAM adapter
:class:`factors.smart.HostPointsFactor` and the hand-rolled solver of
:mod:`gtvo.window.handrolled` (each keeps its own optimisation loop, so the two still check each
other). It owns everything between the photometric kernel and an optimiser: the host samples
and bearings, the variance weights ``W`` (frozen at their first evaluation), the Huber IRLS
weights and losses, the stereo term and the depth prior, the accumulation over targets, the
Schur elimination of the depths, the back-substitution and the safeguarded depth step.

At poses/affines ``x`` and inverse depths ``d``, with the IRLS weights ``w_n`` (Huber on each
point-target pattern norm) and variance weights ``W``::

    H_pp = sum J_p^T wW J_p,  H_pd[n] = sum J_p^T wW J_d,  H_dd[n] = sum wW J_d^2 (+ 1/sigma_prior^2)
    g_p  = sum J_p^T wW r,    g_d[n]  = sum wW J_d r      (+ (d - d_prior)/sigma_prior^2)
    H_red = H_pp - sum_n H_pd H_pd^T / H_dd,    g_red = g_p - sum_n H_pd g_d / H_dd

over the active points (``H_dd`` above 1e-12 of the largest; the others keep their depth). A
step ``dx`` implies the depths ``d + dd``, ``dd = -(g_d + H_pd dx) / H_dd`` (kept >= 0.1 d);
the safeguard lets a point whose cost rose above its cost at the linearisation point keep its
old depth if that costs less (an optimiser damps only ``x``; the undamped depth step raised the
cost of many points near the optimum). Details: docs/factors.md §7, docs/window.md.
"""

from __future__ import annotations

import functools
import sys
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors import _compiled, _compiled_rows, _compiled_sums
from factors.photometric import (GradientImage, GradientSampler, PhotometricLinearization, compiled_residuals,
                                 pair_pose, pattern_bearings, photometric_residuals, put_rows, sample_host,
                                 stereo_pair_pose, stereo_residuals)
from factors.weights import point_robust_terms, variance_weight
from gtvo.core.camera import MIN_DEPTH, PinholeCamera
from gtvo.core.kernel_threads import kernel_threads, map_independent
from gtvo.core.lie import se3_adjoint
from gtvo.core.timing import timed
from gtvo.errors import InputError

FloatArray = NDArray[np.float64]
_NO_AFFINE = np.zeros((0, 1, 2))  # the compiled sums' 'no affine columns'
_EMPTY_ROWS = np.zeros((0, 1))  # the compiled depth terms' 'no stereo term'
#: :meth:`HostPoints.residuals` of fewer points than this run in the caller's thread (kernel threads)
MIN_ROWS_TO_SHARE = 100
#: per host, at most this many sets of pass buffers (:class:`PassBuffers`) are kept for reuse
MAX_PASS_BUFFERS = 4


class PassBuffers:
    """The outputs of one host's residual pass over its T targets and its stereo term, laid out for
    the compiled loops (:func:`factors._compiled.warp_into`): residuals, validity, ``J_depth`` and
    warped pixels stacked ``(T1, N, P...)`` (T1 = T, plus 1 with a stereo term, last), host pose and
    affine Jacobians ``(T, N, P, 6 | 2)``, the stereo term's rig-offset Jacobian ``(N, P, 2)``. A
    pass over ``M <= N`` points uses the first M rows of each target's block (contiguous).

    All arrays are views of one byte block, so whether any linearisation still refers to them
    (a factor's kept pass, the safeguard's merged one, a caller's) is one reference count:
    :meth:`in_use`. A pass takes a set that is not in use; a set in use is never written."""

    def __init__(self, n_targets: int, n: int, p: int, stereo: bool) -> None:
        self._args = (n_targets, n, p, stereo)
        t1 = n_targets + (1 if stereo else 0)
        shapes = {"residual": (t1, n, p), "J_depth": (t1, n, p), "uv": (t1, n, p, 2), "J_host": (n_targets, n, p, 6),
                  "J_affine_host": (n_targets, n, p, 2), "J_offset": (n, p, 2)}
        sizes = {k: 8 * int(np.prod(v)) for k, v in shapes.items()}
        self._block = np.empty(sum(sizes.values()) + t1 * n * p, dtype=np.uint8)
        at = 0
        for name, shape in shapes.items():
            setattr(self, name, self._block[at:at + sizes[name]].view(np.float64).reshape(shape))
            at += sizes[name]
        self.valid = self._block[at:].view(np.bool_).reshape(t1, n, p)
        self.capacity = n
        #: every array as (terms, points, a point's entries), for row copies (:meth:`HostPoints._put_back`)
        self.by_point = {name: a.reshape(a.shape[0], n, k * p) for name, a, k in (
            ("residual", self.residual, 1), ("valid", self.valid, 1), ("J_depth", self.J_depth, 1), ("uv", self.uv, 2),
            ("J_host", self.J_host, 6), ("J_affine_host", self.J_affine_host, 2), ("J_offset", self.J_offset[None], 2))}
        self._free_count = sys.getrefcount(self._block)

    def in_use(self) -> bool:
        """Some array outside this object still refers to the block (a linearisation made from it)."""
        return sys.getrefcount(self._block) > self._free_count

    def __reduce__(self) -> tuple:
        """A copy (pickled, deep-copied) is a new free set: copied linearisations hold copies of their
        arrays, not views of the copied block, and the reference count is this process's own."""
        return PassBuffers, self._args


class PassLinearizations(list):
    """:meth:`HostPoints.residuals`' list (each target's linearisation, then the stereo term's or None)
    when one compiled pass wrote them into :class:`PassBuffers`: ``residual_stack`` is their
    residuals stacked (T1, M, P), which :meth:`HostPoints.point_costs` reads in one compiled loop
    while the list still holds the pass's own linearisations (``residual_arrays``)."""

    def __init__(self, items: list, residual_stack: FloatArray, buffers: PassBuffers | None = None) -> None:
        super().__init__(items)
        self.residual_stack = residual_stack
        self.residual_arrays = [None if lin is None else lin.residual for lin in items]
        #: the :class:`PassBuffers` the pass wrote (its arrays are the items' arrays while
        #: :meth:`writable_buffers` says so)
        self.buffers = buffers

    def unchanged(self) -> bool:
        """Every item is still the pass's linearisation with its residual array (then ``residual_stack``
        holds the residuals the items hold, written in place or not)."""
        return len(self) == len(self.residual_arrays) and all(
            (lin is None and a is None) or (lin is not None and lin.residual is a)
            for lin, a in zip(self, self.residual_arrays))

    def writable_buffers(self, n: int) -> PassBuffers | None:
        """The :class:`PassBuffers` whose rows are these items' rows, when the pass was over all
        ``n`` points and the items are still its own (not copies: a pickled or deep-copied list holds
        arrays of its own, and its ``buffers`` are a new set); else None. Writing a row of these
        buffers writes that point's row of every item."""
        buf = self.buffers
        if (buf is None or self.residual_stack.shape[1] != n or buf.capacity != n or not self.unchanged()
                or self.residual_stack.ctypes.data != buf.residual.ctypes.data):
            return None
        return buf


def gauss_newton_sums(lin: PhotometricLinearization, weight: ArrayLike, with_affine: bool = True
                      ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Gauss-Newton sums of one host-target linearisation (the window's Hessian accumulation).

    With ``J = [J_host, J_affine_host, J_target, J_affine_target]`` per residual (this block
    order; without ``with_affine`` the two pose blocks only), ``w = weight`` (N, P) (the
    variance weight W times the point's robust weight), ``r`` the residual and ``j`` its
    ``J_depth``:

        H = sum w J^T J   (16, 16 or 12, 12)      g = sum w J^T r
        H_pd[n] = sum_P w j J   (N, k)            H_dd[n] = sum_P w j^2    g_d[n] = sum_P w j r

    The pose-depth blocks stay per point for the Schur complement. One compiled loop: when the
    linearisation carries its pair's ``T_target_host`` and brightness gain (the kernels of
    :mod:`factors.photometric` set them), :func:`factors._compiled_sums.accumulate_pair`, which sums
    over the host Jacobians only and maps the sums to the target blocks
    (:func:`target_jacobian_map`; 2-3x faster); else :func:`factors._compiled_sums.accumulate_target`.
    Both are tested against the numpy sums.

    Raises:
        InputError: the linearisation has no host Jacobians (``jacobians=False`` or
            ``host_jacobians=False``), or no target Jacobians and no pair pose to map them by,
            or ``weight`` has the wrong shape.
    """
    pair = lin.has_pair_pose
    if lin.J_host is None or (lin.J_target is None and not pair):
        raise InputError("gauss_newton_sums needs a linearisation with host and target Jacobians (or host "
                         "Jacobians and the pair's relative pose)")
    w = np.ascontiguousarray(weight, dtype=float)
    if w.shape != lin.residual.shape:
        raise InputError(f"gauss_newton_sums: weight has shape {w.shape}, residuals {lin.residual.shape}")
    p = lin.residual.shape[1]
    if with_affine:
        if lin.J_affine_host is None or (lin.J_affine_target is None and not pair):
            raise InputError("gauss_newton_sums: with_affine needs the affine Jacobians")
        ah = np.ascontiguousarray(lin.J_affine_host)
    else:
        ah = np.zeros((0, p, 2))
    if pair:
        return _compiled_sums.accumulate_pair(np.ascontiguousarray(lin.J_host), ah,
                                              target_jacobian_map(lin.T_target_host), float(lin.brightness_gain),
                                              w, np.ascontiguousarray(lin.residual), np.ascontiguousarray(lin.J_depth),
                                              np.ascontiguousarray(lin.valid, dtype=bool))
    at = np.ascontiguousarray(lin.J_affine_target) if with_affine else ah
    return _compiled_sums.accumulate_target(np.ascontiguousarray(lin.J_host), ah, np.ascontiguousarray(lin.J_target),
                                            at, w, np.ascontiguousarray(lin.residual),
                                            np.ascontiguousarray(lin.J_depth))


def target_normal_equations(lin: PhotometricLinearization, weight: ArrayLike, with_affine: bool = True
                            ) -> tuple[FloatArray, FloatArray]:
    """The normal equations of the target's pose (and affine) alone, the tracker's Gauss-Newton step:
    ``A = sum w J^T J`` (8, 8 or 6, 6), ``b = sum w J^T r`` with ``J = [J_target, J_affine_target]``
    per residual and ``w = weight`` (N, P). One compiled loop
    (:func:`factors._compiled_sums.target_normal_equations`), tested against the numpy sums.

    Raises:
        InputError: the linearisation has no target Jacobians, or ``weight`` has the wrong shape.
    """
    if lin.J_target is None or (with_affine and lin.J_affine_target is None):
        raise InputError("target_normal_equations needs a linearisation with target Jacobians")
    w = np.ascontiguousarray(weight, dtype=float)
    if w.shape != lin.residual.shape:
        raise InputError(f"target_normal_equations: weight has shape {w.shape}, residuals {lin.residual.shape}")
    aff = np.ascontiguousarray(lin.J_affine_target) if with_affine else _NO_AFFINE
    return _compiled_sums.target_normal_equations(np.ascontiguousarray(lin.J_target), aff, w,
                                                  np.ascontiguousarray(lin.residual))


def target_jacobian_map(T_target_host: ArrayLike) -> FloatArray:
    """``B`` (6, 6) with ``J_target = J_host B^T`` for every photometric residual of a host-target pair
    evaluated at ``T_target_host = (R, t)`` (poses right-perturbed, ``[rotation, translation]``):
    ``B = -[[R, [t]x R], [0, R]] = -Ad(T_target_host)^-T`` (GTSAM's adjoint in this order). The
    residual depends on the two poses only through ``T_target_host = T_world_target^-1
    T_world_host``; perturbing the host by ``xi`` moves it like perturbing the target by
    ``eta = -Ad(T_target_host) xi``, so ``J_host = -J_target Ad`` (docs/factors.md §7; tested
    against the kernels' own ``J_target``)."""
    T = np.asarray(T_target_host, dtype=float)
    R, t = T[:3, :3], T[:3, 3]
    return -se3_adjoint(R.T, -R.T @ t).T  # Ad^-1 is the adjoint of the inverse pose


def target_jacobian_maps(T_target_host: ArrayLike) -> FloatArray:
    """:func:`target_jacobian_map` of a stack of poses (K, 4, 4) -> (K, 6, 6) in one vectorised call
    (a host's pairs at once; the same values, the same products)."""
    T = np.asarray(T_target_host, dtype=float)
    R, t = T[:, :3, :3], T[:, :3, 3]
    Rt = R.transpose(0, 2, 1)
    u = (-Rt @ t[..., None])[..., 0]  # the inverse poses' translations
    # se3_adjoint(Rt, u) built in place (its values: the same products; 2x faster for a host's pairs)
    k = T.shape[0]
    hat = np.zeros((k, 3, 3))
    hat[:, 0, 1], hat[:, 0, 2], hat[:, 1, 2] = -u[:, 2], u[:, 1], -u[:, 0]
    hat[:, 1, 0], hat[:, 2, 0], hat[:, 2, 1] = u[:, 2], -u[:, 1], u[:, 0]
    ad = np.zeros((k, 6, 6))
    ad[:, :3, :3] = Rt
    ad[:, 3:, 3:] = Rt
    ad[:, 3:, :3] = hat @ Rt
    return -ad.transpose(0, 2, 1)


def keep_cheaper_depths(d: FloatArray, c: FloatArray, lins: list, rows: NDArray[np.intp], d_old: FloatArray,
                        c_old: FloatArray, lins_old: list) -> tuple[FloatArray, FloatArray, list]:
    """The safeguarded depth step's merge: of the points ``rows`` (whose cost at the new depths
    ``d`` rose), those that cost less at their old depth (``c_old``, ``lins_old``: evaluated for
    ``rows`` only) take it back. Returns ``(depths, point costs, linearisations)``; ``d`` and ``c``
    are not modified, ``lins`` (the caller's fresh residuals at ``d``) are updated in place."""
    keep = np.flatnonzero(c_old < c[rows])
    if not keep.size:
        return d, c, lins
    r = rows[keep]
    d, c = d.copy(), c.copy()
    d[r], c[r] = d_old[r], c_old[keep]
    return d, c, [None if a is None else put_rows(a, r, b, keep) for a, b in zip(lins, lins_old)]


@dataclass(frozen=True)
class HostSamples:
    """What a host's points need of the host image and the camera, fixed for the host's life: the
    host intensities and their validity at the pattern around each point (N, P) and the pattern
    pixels' bearings (N, P, 3) (:meth:`of`). Shared by the host's factors, never written."""

    intensity: FloatArray  #: (N, P) host intensities
    valid: NDArray[np.bool_]  #: (N, P) host samples inside the image (and unclipped)
    bearings: FloatArray  #: (N, P, 3) ``K^-1 [u, v, 1]``

    @classmethod
    def of(cls, camera: PinholeCamera, pixels: ArrayLike, host_image: GradientSampler, pattern: ArrayLike
           ) -> HostSamples:
        """Sample the host image and the bearings at the pattern around ``pixels`` (N, 2)."""
        px = np.asarray(pixels, dtype=float).reshape(-1, 2)
        intensity, valid = sample_host(host_image, px, pattern)
        return cls(intensity, valid, pattern_bearings(camera, px, pattern))


@dataclass
class DepthSystem:
    """The per-point blocks of one linearisation of a host's points (:meth:`HostPoints.linearize`).

    ``H_pd`` has one column per entry of the caller's state vector; ``H_dd`` is 1 for the
    inactive points (no curvature), which keep their depth.
    """

    d: FloatArray  #: (N,) inverse depths at the linearisation point
    H_pd: FloatArray  #: (N, M)
    H_dd: FloatArray  #: (N,)
    g_d: FloatArray  #: (N,)
    active: NDArray[np.bool_]  #: (N,) points with curvature
    point_cost: FloatArray  #: (N,) each point's cost at the linearisation point

    def back_substitute(self, dx: FloatArray) -> FloatArray:
        """The inverse depths implied by the state step ``dx`` (M,): ``d - (g_d + H_pd dx) / H_dd``,
        kept at least ``0.1 d`` (> 0; an optimiser rejects such far steps anyway)."""
        a = self.active
        if a.all():  # the usual case: no row selection (the same products)
            step = -(self.g_d + self.H_pd @ dx) / self.H_dd
        else:
            step = np.zeros_like(self.d)
            step[a] = -(self.g_d[a] + self.H_pd[a] @ dx) / self.H_dd[a]
        return np.maximum(self.d + step, 0.1 * self.d)

    def newton_decrease(self) -> float:
        """The decrease of the cost's Gauss-Newton model from the depth-only Newton step at ``dx = 0``:
        ``sum_n g_d^2 / (2 H_dd)`` over the active points."""
        a = self.active
        if a.all():
            return 0.5 * float(np.sum(self.g_d ** 2 / self.H_dd))
        return 0.5 * float(np.sum(self.g_d[a] ** 2 / self.H_dd[a]))


class HostPoints:
    """All points hosted in one keyframe and observed in T target images (T >= 0).

    Poses and affines are passed as lists, host first then the targets in order: ``poses`` of
    ``T_world_cam`` (``gtsam.Pose3`` or 4x4), ``affines`` of ``(a, b)`` (ignored without
    ``with_affine``: all zero). Inverse depths ``d`` are (N,) arrays held by the caller.

    Args:
        camera: intrinsics (all images share them).
        pixels: (N, 2) host pixels.
        host_image: the host image with gradients; target_images: one per target.
        inverse_depth_variance: (N,) V used in the weight W (and, with ``depth_prior``, as the
            prior's variance).
        prior_inverse_depth: (N,) the depth prior's mean (e.g. the stereo estimate).
        sigma_intensity, huber_k, pattern: the weight's intensity noise, the Huber threshold on a
            point's whitened pattern norm (None: no kernel) and the (P, 2) residual pattern.
        depth_prior: add ``(d - prior)^2 / V`` to each point's cost (it also fixes depths of points
            seen in no target).
        with_affine: the affines are variables (16 Jacobian columns per target, else 12).
        right_image, baseline, lambda_stereo, stereo_affine: the host frame's stereo energy
            ``lambda E_s`` (:func:`factors.photometric.stereo_residuals`, right image's ``(a, b)``
            relative to the left one held fixed); it involves the depths (and the rig offset).
        rig: the stereo term's rig offset ``(delta_x, delta_y)`` (px, :func:`stereo_residuals`'
            ``offset``) is a variable: :meth:`residuals` take it as ``offset`` and
            :meth:`linearize` adds its two columns (``rig_columns``) to the reduced system, a
            non-depth parameter like a pose (the Schur complement over the depths is unchanged).
            Without it the stereo term uses ``offset`` (default zero) as a constant.
        host_samples: :meth:`HostSamples.of` these pixels, host image and pattern, when the caller
            keeps them (a keyframe's factor is built again at every window solve); None: sampled here.

    The variance weights W are frozen at their first evaluation (:meth:`weights`) and released by
    :meth:`release_weights`: with W moving with the state the Gauss-Newton model would not match
    the cost an optimiser compares, and LM stalls (docs/factors.md §4).
    """

    def __init__(self, camera: PinholeCamera, pixels: ArrayLike, host_image: GradientSampler,
                 target_images: Sequence[GradientSampler], inverse_depth_variance: ArrayLike | float,
                 prior_inverse_depth: ArrayLike, *, sigma_intensity: float, huber_k: float | None,
                 pattern: ArrayLike, depth_prior: bool, with_affine: bool = True,
                 right_image: GradientSampler | None = None, baseline: float | None = None,
                 lambda_stereo: float = 1.0, stereo_affine: ArrayLike = (0.0, 0.0), rig: bool = False,
                 host_samples: HostSamples | None = None) -> None:
        self.camera = camera
        self.pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
        n = self.pixels.shape[0]
        if n == 0:
            raise InputError("HostPoints: need N > 0 points")
        self.variance = np.broadcast_to(np.asarray(inverse_depth_variance, dtype=float), (n,)).copy()
        self.depth_prior = bool(depth_prior)
        if self.depth_prior and not np.all(self.variance > 0):
            raise InputError("HostPoints: a depth prior needs positive inverse-depth variances")
        self.prior = np.asarray(prior_inverse_depth, dtype=float).reshape(-1).copy()
        if self.prior.shape[0] != n or not np.all(np.isfinite(self.prior)):
            raise InputError(f"HostPoints: prior_inverse_depth must hold {n} finite values")
        if right_image is not None:
            if baseline is None or not (np.isfinite(baseline) and baseline > 0):
                raise InputError(f"HostPoints: a stereo term needs a positive baseline, got {baseline!r}")
            if not (np.isfinite(lambda_stereo) and lambda_stereo > 0):
                raise InputError(f"HostPoints: lambda_stereo must be positive, got {lambda_stereo!r}")
        self.pattern = np.asarray(pattern, dtype=float).reshape(-1, 2)
        if host_samples is None:
            host_samples = HostSamples.of(camera, self.pixels, host_image, self.pattern)
        elif (host_samples.intensity.shape != (n, self.pattern.shape[0])
              or host_samples.bearings.shape[:2] != (n, self.pattern.shape[0])):
            raise InputError(f"HostPoints: host_samples of shape {host_samples.intensity.shape} for {n} points "
                             f"x {self.pattern.shape[0]} pattern pixels")
        # fixed: host pixels only (shared, never written)
        self.host_intensity, self.host_valid = host_samples.intensity, host_samples.valid
        self.bearings = host_samples.bearings
        self.target_images = list(target_images)
        self.sigma = float(sigma_intensity)
        self.huber_k = huber_k
        self.with_affine = bool(with_affine)
        self.right_image = right_image
        self.baseline = None if baseline is None else float(baseline)
        self.lambda_stereo = float(lambda_stereo)
        self.stereo_affine = np.asarray(stereo_affine, dtype=float).reshape(2)
        #: the rig offset (delta_x, delta_y) of the stereo term is a variable (its 2 columns in the state)
        self.rig = bool(rig) and right_image is not None
        self.W: list[FloatArray] | None = None
        self._W_stack: tuple[list, FloatArray] | None = None  # (self.W, its arrays stacked (T1, N, P))
        # the compiled pass (_compiled_pass): every image a GradientImage; inputs laid out once
        self._compiled = (all(isinstance(img, GradientImage) for img in self.target_images)
                          and (right_image is None or isinstance(right_image, GradientImage)))
        self._host_intensity_c = np.ascontiguousarray(self.host_intensity, dtype=float)
        self._host_valid_c = np.ascontiguousarray(self.host_valid, dtype=bool)
        self._all_rows = np.arange(n, dtype=np.intp)
        self._stereo_pose = None if right_image is None else stereo_pair_pose(self.baseline)
        self._buffers: list[PassBuffers] = []
        self._pairs: tuple[tuple, list] | None = None  # (the poses, their pair_pose per target)
        p = self.pattern.shape[0]
        self._no_rows6, self._no_rows2 = np.empty((0, p, 6)), np.empty((0, p, 2))
        self._intrinsics = (float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy), float(MIN_DEPTH))
        self._gains: dict[float, float] = {}  # exp of a pair's log gain, by its exact value

    def __len__(self) -> int:
        return int(self.pixels.shape[0])

    # --- residuals and weights ---------------------------------------------------------------
    @timed("linearisation")
    def residuals(self, poses: Sequence, affines: Sequence | None, d: FloatArray,
                  rows: NDArray[np.intp] | None = None, offset: ArrayLike | None = None,
                  jacobians: bool = True) -> list:
        """Linearisations (with Jacobians) of every target, then the stereo term (or None), of all
        points or of the points ``rows`` (``d`` is always the full (N,) vector); ``offset``: the
        rig offset of the stereo term (None: zero, the rectified model); ``jacobians=False``: the
        residuals, validity and ``J_depth`` only (a cost, not a linearisation: the same values,
        without the pose, affine and offset Jacobians and their memory). For a
        :class:`GradientImage` target ``J_target`` and ``J_affine_target`` are None (the sums map
        them from the host Jacobians with the pair's pose, :func:`gauss_newton_sums`); other
        samplers give them.

        An optimiser evaluates the cost at a trial state and, when it accepts it, linearises at the
        same state: the Jacobians cost about a third of a pass (the bilinear gathers being the
        rest), so the cost pass computes them and the linearisation reuses its output.

        The calls of :meth:`residual_calls`, on the process's kernel threads
        (:func:`gtvo.core.kernel_threads.map_independent`: one thread unless the window's worker
        set more; the results do not depend on it). A few ``rows`` (fewer than
        :data:`MIN_ROWS_TO_SHARE`, the safeguard's points whose cost rose) run in this thread: a
        hand-over to another would cost more than their loops.
        """
        if self._compiled and kernel_threads() <= 1:
            return self._compiled_pass(poses, affines, d, rows, offset, jacobians)
        calls = self.residual_calls(poses, affines, d, rows, offset, jacobians)
        if rows is not None and rows.size < MIN_ROWS_TO_SHARE:
            return [call() for call in calls]
        return map_independent(calls)

    def _pair_poses(self, poses: Sequence) -> list:
        """:func:`factors.photometric.pair_pose` of every target, once per set of poses: the passes at
        one state (the safeguard's two, a cost pass then its linearisation) are given the same pose
        objects, immutable ``gtsam.Pose3`` (arrays are not cached: they could change in place)."""
        cached = self._pairs
        if cached is not None and len(cached[0]) == len(poses) and all(a is b for a, b in zip(cached[0], poses)):
            return cached[1]
        pairs = [pair_pose(poses[0], poses[1 + t]) for t in range(len(self.target_images))]
        if all(hasattr(T, "between") for T in poses):
            self._pairs = (tuple(poses), pairs)
        return pairs

    def _gain(self, log_gain: float) -> float:
        """``exp(log_gain)`` as :func:`factors.photometric.compiled_residuals` computes it, remembered by
        the exact value (the passes at one state ask again; a few hundred values per solve at most)."""
        e = self._gains.get(log_gain)
        if e is None:
            if len(self._gains) > 256:
                self._gains.clear()
            e = self._gains[log_gain] = float(np.exp(log_gain))
        return e

    def _pass_buffers(self) -> PassBuffers:
        """A set of :class:`PassBuffers` no linearisation refers to (a kept one, or a new one)."""
        for b in self._buffers:
            if not b.in_use():
                return b
        b = PassBuffers(len(self.target_images), len(self), self.pattern.shape[0], self.right_image is not None)
        if len(self._buffers) < MAX_PASS_BUFFERS:
            self._buffers.append(b)
        return b

    def _compiled_pass(self, poses: Sequence, affines: Sequence | None, d: FloatArray,
                       rows: NDArray[np.intp] | None, offset: ArrayLike | None, jacobians: bool) -> PassLinearizations:
        """:meth:`residuals` as one compiled call per target and one for the stereo term
        (:func:`factors._compiled.warp_into`), the points ``rows`` read in place, the outputs written
        into :class:`PassBuffers` this host keeps (none that a linearisation still refers to): no
        allocation, no gathered copies, the pair poses once per state. The values of
        :meth:`residual_calls`, to the bit (the same loops on the same inputs)."""
        idx = self._all_rows if rows is None else np.ascontiguousarray(rows, dtype=np.intp)
        m = idx.shape[0]
        nt = len(self.target_images)
        buf = self._pass_buffers()
        cam = self.camera
        fx, fy, cx, cy, min_depth = self._intrinsics
        f, Ih, hv = self.bearings, self._host_intensity_c, self._host_valid_c
        dc = np.ascontiguousarray(d, dtype=float)
        counts = np.zeros((nt + 1, 3), dtype=np.int64)
        zero = np.zeros(2)
        ah = np.asarray(affines[0] if self.with_affine else zero, dtype=float)
        b_h = float(ah[1])
        lins: list = []
        for t, (T, R, tv) in enumerate(self._pair_poses(poses)):
            at = np.asarray(affines[1 + t] if self.with_affine else zero, dtype=float)
            e = self._gain(float(at[0] - ah[0]))
            Jh = buf.J_host[t, :m] if jacobians else self._no_rows6
            Jah = buf.J_affine_host[t, :m] if jacobians else self._no_rows2
            r, valid, Jd, uv = buf.residual[t, :m], buf.valid[t, :m], buf.J_depth[t, :m], buf.uv[t, :m]
            _compiled.warp_into(*self.target_images[t]._sampler_args(), fx, fy, cx, cy, min_depth, R, tv, f,
                                dc, Ih, hv, idx, e, b_h, float(at[1]), jacobians, True, False, False,
                                r, valid, Jd, uv, self._no_rows6, Jh, self._no_rows2, Jah, self._no_rows2, counts[t])
            nb, nbh, no = counts[t].tolist()
            if jacobians:
                lins.append(PhotometricLinearization(r, valid, Jd, Jh, None, Jah, None, uv, nb, nbh, no,
                                                     T_target_host=T, brightness_gain=e))
            else:
                lins.append(PhotometricLinearization(r, valid, Jd, None, None, None, None, uv, nb, nbh, no))
        if self.right_image is None:
            lins.append(None)
            return PassLinearizations(lins, buf.residual[:, :m], buf)
        # the stereo term (stereo_residuals): the right camera's warp, its principal point moved by the offset
        scx, scy = cx, cy
        if offset is not None:
            dx, dy = (float(x) for x in np.asarray(offset, dtype=float).reshape(2))
            if not (np.isfinite(dx) and np.isfinite(dy)):
                raise InputError(f"stereo_residuals: rig offset must be finite, got {(dx, dy)!r}")
            if dx != 0.0 or dy != 0.0:
                scx, scy = float(cam.cx + dx), float(cam.cy + dy)
        a_r, b_r = (float(x) for x in self.stereo_affine)
        with_offset = self.rig and jacobians
        Jo = buf.J_offset[:m] if with_offset else self._no_rows2
        r, valid, Jd, uv = buf.residual[nt, :m], buf.valid[nt, :m], buf.J_depth[nt, :m], buf.uv[nt, :m]
        _, R, tv = self._stereo_pose
        _compiled.warp_into(*self.right_image._sampler_args(), fx, fy, scx, scy, min_depth, R, tv, f, dc, Ih,
                            hv, idx, float(np.exp(a_r - 0.0)), 0.0, b_r, False, False, False, with_offset,
                            r, valid, Jd, uv, self._no_rows6, self._no_rows6, self._no_rows2, self._no_rows2, Jo,
                            counts[nt])
        nb, nbh, no = counts[nt].tolist()
        lins.append(PhotometricLinearization(r, valid, Jd, None, None, None, None, uv, nb, nbh, no,
                                             J_offset=Jo if with_offset else None))
        return PassLinearizations(lins, buf.residual[:, :m], buf)

    def residual_calls(self, poses: Sequence, affines: Sequence | None, d: FloatArray,
                       rows: NDArray[np.intp] | None = None, offset: ArrayLike | None = None,
                       jacobians: bool = True) -> list[Callable[[], PhotometricLinearization | None]]:
        """:meth:`residuals` as independent calls, one per target then the stereo term's (each returns
        its linearisation, the stereo one None without a right image): they share no mutable state,
        so a caller may run them on several threads, and those of several hosts together."""
        sel = slice(None) if rows is None else rows
        Ih, hv, px, f, ds = self.host_intensity[sel], self.host_valid[sel], self.pixels[sel], self.bearings[sel], d[sel]
        zero = np.zeros(2)
        ah = np.asarray(affines[0] if self.with_affine else zero, dtype=float)
        # laid out once for the compiled loops of every target (compiled_residuals skips the checks)
        Ih_c, hv_c = np.ascontiguousarray(Ih, dtype=float), np.ascontiguousarray(hv, dtype=bool)
        f_c, ds_c = np.ascontiguousarray(f, dtype=float), np.ascontiguousarray(ds, dtype=float)

        def target(t: int) -> PhotometricLinearization:
            img = self.target_images[t]
            at = np.asarray(affines[1 + t] if self.with_affine else zero, dtype=float)
            if isinstance(img, GradientImage):
                return compiled_residuals(self.camera, Ih_c, hv_c, f_c, ds_c, poses[0], poses[1 + t], img,
                                          float(at[0] - ah[0]), float(ah[1]), float(at[1]),
                                          jacobians=jacobians, target_jacobians=False)  # mapped from J_host in the sums
            return photometric_residuals(self.camera, Ih, hv, px, ds, poses[0], poses[1 + t], img, ah, at,
                                         self.pattern, jacobians=jacobians, host_jacobians=True, bearings=f)

        def stereo() -> PhotometricLinearization | None:
            if self.right_image is None:
                return None
            return stereo_residuals(self.camera, self.baseline, Ih, hv, px, ds, self.right_image, (0.0, 0.0),
                                    self.stereo_affine, self.pattern, jacobians=False, bearings=f, offset=offset,
                                    offset_jacobians=self.rig and jacobians)

        return [functools.partial(target, t) for t in range(len(self.target_images))] + [stereo]

    def weights(self, lins: list) -> list[FloatArray]:
        """W per target (then ``lambda`` W of the stereo term): frozen at the first call, from the
        :meth:`residuals` ``lins`` of all points given then."""
        if self.W is None:
            W = [variance_weight(lin.J_depth, self.variance, self.sigma) for lin in lins[:-1]]
            if lins[-1] is not None:
                W.append(self.lambda_stereo * variance_weight(lins[-1].J_depth, self.variance, self.sigma))
            self.W = W
        return self.W

    def release_weights(self) -> None:
        """Forget the frozen W: the next evaluation freezes them again at its state."""
        self.W = None
        self._W_stack = None

    def _stacked_weights(self, Ws: list[FloatArray]) -> FloatArray:
        """The frozen ``Ws`` stacked (T1, N, P), made once per freeze."""
        cached = self._W_stack
        if cached is None or cached[0] is not Ws:
            cached = self._W_stack = (Ws, np.stack(Ws))
        return cached[1]

    @timed("linearisation")
    def point_costs(self, lins: list, d: FloatArray, rows: NDArray[np.intp] | None = None) -> FloatArray:
        """Each point's cost from its :meth:`residuals`: robust photometric and stereo losses and
        the depth prior (``rows``: ``lins`` hold only these points; W must be frozen already)."""
        sel = slice(None) if rows is None else rows
        assert rows is None or self.W is not None
        Ws = self.weights(lins)
        stack = getattr(lins, "residual_stack", None)
        if stack is not None and lins.unchanged():
            # a compiled pass's residuals: every term's robust loss in one compiled loop
            W_stack = self._stacked_weights(Ws)
            idx = self._all_rows if rows is None else np.ascontiguousarray(rows, dtype=np.intp)
            return _compiled.stacked_point_losses(W_stack, stack, idx, 0.0 if self.huber_k is None else
                                                  float(self.huber_k), self.huber_k is not None,
                                                  np.ascontiguousarray(d, dtype=float), self.prior, self.variance,
                                                  self.depth_prior)
        c = np.zeros(d.shape[0] if rows is None else rows.size)
        for W, lin in zip(Ws, lins):
            c += point_robust_terms(W[sel], lin.residual, self.huber_k)[1]
        if self.depth_prior:
            c += 0.5 * (d[sel] - self.prior[sel]) ** 2 / self.variance[sel]
        return c

    # --- linearisation -----------------------------------------------------------------------
    @timed("linearisation")
    def linearize(self, lins: list, d: FloatArray, H: FloatArray, g: FloatArray,
                  columns: Sequence[NDArray[np.intp]], rig_columns: ArrayLike | None = None) -> DepthSystem:
        """Add this host's Gauss-Newton terms, depths eliminated, to the caller's ``H`` (M, M), ``g`` (M,).

        ``lins``: :meth:`residuals` at this state (all points); ``columns[t]``: the entries of the
        caller's state vector of target t's :func:`gauss_newton_sums` block (host pose, [host
        affine,] target pose[, target affine]); ``rig_columns``: the two entries of the rig offset
        (needed with ``rig``). Returns the per-point blocks and costs.
        """
        n = d.shape[0]
        H_pd = np.zeros((n, H.shape[0]))
        H_dd = np.zeros(n)
        g_d = np.zeros(n)
        c = np.zeros(n)
        Ws = self.weights(lins)
        k, robust = (0.0 if self.huber_k is None else float(self.huber_k)), self.huber_k is not None
        # the pairs' maps B in one batched call (the same values as one call per pair)
        paired = [t for t in range(len(columns)) if lins[t].has_pair_pose and lins[t].J_host is not None]
        maps = dict(zip(paired, target_jacobian_maps(np.stack([lins[t].T_target_host for t in paired])))) if paired else {}
        for t, cols in enumerate(columns):
            lin, W = lins[t], Ws[t]
            if t in maps:
                # the loop below as one compiled call (the pair's sums from the host Jacobians); it
                # indexes without bounds checks, so the shapes are checked here
                if (len(cols) != (16 if self.with_affine else 12) or W.shape != lin.residual.shape
                        or lin.valid.shape != W.shape):
                    raise InputError(f"HostPoints.linearize: target {t} has {len(cols)} columns and weights "
                                     f"{W.shape} for residuals {lin.residual.shape} (with_affine={self.with_affine})")
                _compiled_sums.add_pair_terms(
                    lin.J_host, lin.J_affine_host if self.with_affine else _NO_AFFINE, maps[t],
                    float(lin.brightness_gain), W, lin.residual, lin.J_depth, lin.valid, k, robust, cols, H, g, H_pd,
                    H_dd, g_d, c)
                continue
            w, loss = point_robust_terms(W, lin.residual, self.huber_k)
            H_t, g_t, H_pd_t, H_dd_t, g_d_t = gauss_newton_sums(lin, W * w[:, None], self.with_affine)
            c += loss
            H[np.ix_(cols, cols)] += H_t
            g[cols] += g_t
            H_pd[:, cols] += H_pd_t
            H_dd += H_dd_t
            g_d += g_d_t
        st = lins[-1]
        w = self._add_depth_terms(st, None if st is None else Ws[-1], d, H_dd, g_d, c)
        if st is not None and self.rig:
            if rig_columns is None or st.J_offset is None:
                raise InputError("HostPoints.linearize: a rig offset variable needs rig_columns and "
                                 "residuals with offset Jacobians")
            rc = np.asarray(rig_columns, dtype=np.intp)
            Jo = st.J_offset.reshape(-1, 2)
            wJo = (Ws[-1] * w[:, None]).reshape(-1, 1) * Jo
            H[np.ix_(rc, rc)] += Jo.T @ wJo
            g[rc] += wJo.T @ st.residual.reshape(-1)
            H_pd[:, rc] += np.sum((wJo * st.J_depth.reshape(-1, 1)).reshape(n, -1, 2), axis=1)
        return self._eliminate(DepthSystem(d.copy(), H_pd, H_dd, g_d, np.ones(n, dtype=bool), c), H, g)

    def _add_depth_terms(self, stereo: PhotometricLinearization | None, W: FloatArray | None, d: FloatArray,
                         H_dd: FloatArray, g_d: FloatArray, c: FloatArray) -> FloatArray:
        """The terms on the depths alone, added in place: the stereo term's (``stereo`` with its
        weights ``W``; None: no stereo term) robust sums ``H_dd += sum_P wW j^2``, ``g_d += sum_P
        wW j r`` and losses, then the depth prior's ``1 / V``, ``(d - prior) / V`` and
        ``(d - prior)^2 / (2 V)``. Returns the stereo term's Huber weights (N,) (ones without it).
        One compiled pass (:func:`factors._compiled_sums.add_depth_terms`, the same values as these
        numpy expressions, which patterns longer than its row sums take)."""
        n = d.shape[0]
        if stereo is not None and stereo.residual.shape[1] > _compiled_sums.MAX_PAIRWISE:
            w, loss = point_robust_terms(W, stereo.residual, self.huber_k)
            ww = W * w[:, None]
            H_dd += np.sum(ww * stereo.J_depth ** 2, axis=1)
            g_d += np.sum(ww * stereo.J_depth * stereo.residual, axis=1)
            c += loss
            if self.depth_prior:
                _compiled_sums.add_depth_terms(_EMPTY_ROWS, _EMPTY_ROWS, _EMPTY_ROWS, 0.0, False, False, d,
                                               self.prior, self.variance, True, H_dd, g_d, c)
            return w
        if stereo is None:
            if not self.depth_prior:
                return np.ones(n)
            args = (_EMPTY_ROWS, _EMPTY_ROWS, _EMPTY_ROWS)
        else:
            if W.shape != stereo.residual.shape or stereo.J_depth.shape != W.shape or W.shape[0] != n:
                raise InputError(f"HostPoints.linearize: the stereo term has weights {W.shape} for residuals "
                                 f"{stereo.residual.shape} of {n} points")
            args = (np.ascontiguousarray(W), np.ascontiguousarray(stereo.residual),
                    np.ascontiguousarray(stereo.J_depth))
        return _compiled_sums.add_depth_terms(*args, 0.0 if self.huber_k is None else float(self.huber_k),
                                              self.huber_k is not None, stereo is not None, d, self.prior,
                                              self.variance, self.depth_prior, H_dd, g_d, c)

    @staticmethod
    def _eliminate(system: DepthSystem, H: FloatArray, g: FloatArray) -> DepthSystem:
        """Schur-eliminate the active depths from ``H``, ``g`` in place:
        ``H -= sum_n H_pd H_pd^T / H_dd``, ``g -= sum_n H_pd g_d / H_dd`` (all points active, the
        usual case: no row selection, the same products)."""
        H_dd = system.H_dd
        active = H_dd > 1e-12 * max(float(H_dd.max()), 1e-300)
        if active.all():
            L = system.H_pd / H_dd[:, None]
            H -= L.T @ system.H_pd
            g -= L.T @ system.g_d
            system.active = active
            return system
        Hdd = np.where(active, H_dd, 1.0)
        L = system.H_pd[active] / Hdd[active, None]
        H -= L.T @ system.H_pd[active]
        g -= L.T @ system.g_d[active]
        system.H_dd, system.active = Hdd, active
        return system

    @timed("linearisation")
    def safeguard(self, poses: Sequence, affines: Sequence | None, system: DepthSystem, d: FloatArray,
                  lins: list, offset: ArrayLike | None = None, jacobians: bool = True
                  ) -> tuple[FloatArray, FloatArray, list]:
        """The safeguarded depth step at a trial state: ``d`` are :meth:`DepthSystem.back_substitute`'s
        depths and ``lins`` the :meth:`residuals` there (``jacobians``: as they were evaluated); the
        points whose cost rose above their cost at ``system``'s linearisation point and that cost
        less at their depth there keep it (a point whose depth did not move costs the same there:
        it is not evaluated again).
        Returns ``(point costs, depths, linearisations)`` (``d`` itself when no point goes back);
        ``lins`` are updated in place (the points that go back get their rows at the old depth).

        When ``lins`` are a compiled pass over all points still in its :class:`PassBuffers`
        (:meth:`PassLinearizations.writable_buffers`), the points whose cost rose are evaluated at
        their old depth into a free buffer set and the rows of those that go back copied into
        ``lins``' buffers, one compiled copy per array for all terms (:meth:`_put_back`; evaluating
        them without Jacobians and those that go back again with them measured 1.25x slower). Else
        their old depth is evaluated apart and merged (:func:`keep_cheaper_depths`). The same
        numbers either way (each point's residuals depend on its own depth only)."""
        c = self.point_costs(lins, d)
        rows = np.flatnonzero((c > system.point_cost) & (d != system.d))
        if not rows.size:
            return c, d, lins
        target = lins.writable_buffers(len(self)) if isinstance(lins, PassLinearizations) else None
        if target is None or not self._compiled or kernel_threads() > 1 or self._pass_jacobians(lins) != jacobians:
            lins_old = self.residuals(poses, affines, system.d, rows, offset, jacobians=jacobians)
            d, c, lins = keep_cheaper_depths(d, c, lins, rows, system.d, self.point_costs(lins_old, system.d, rows),
                                             lins_old)
            return c, d, lins
        old = self._compiled_pass(poses, affines, system.d, rows, offset, jacobians=jacobians)
        c_old = self.point_costs(old, system.d, rows)
        keep = np.flatnonzero(c_old < c[rows])
        if not keep.size:
            return c, d, lins
        r = rows[keep]
        self._put_back(target, r, old.buffers, keep, jacobians)
        d, c = d.copy(), c.copy()
        d[r], c[r] = system.d[r], c_old[keep]
        return c, d, lins

    def _pass_jacobians(self, lins: list) -> bool:
        """Whether the pass ``lins`` came with Jacobians (host Jacobians; without targets, the rig
        offset's; a pass without either has no Jacobians to want)."""
        if self.target_images:
            return lins[0].J_host is not None
        return lins[-1] is not None and lins[-1].J_offset is not None if self.rig else True

    def _put_back(self, target: PassBuffers, rows: NDArray[np.intp], source: PassBuffers,
                  source_rows: NDArray[np.intp], jacobians: bool) -> None:
        """Copy the points ``source_rows`` of a rows pass in ``source`` into the points ``rows`` of a
        pass over all points in ``target``: residuals, validity, ``J_depth`` and warped pixels of
        every term, with ``jacobians`` the host pose and affine Jacobians and the rig offset's too
        (what :func:`factors.photometric.put_rows` copies), one compiled copy per array for all
        terms (:func:`factors._compiled_rows.copy_rows`)."""
        names = ["residual", "valid", "J_depth", "uv"]
        if jacobians:
            names += ["J_host", "J_affine_host", "J_offset"] if self.rig else ["J_host", "J_affine_host"]
        for name in names:
            _compiled_rows.copy_rows(target.by_point[name], rows, source.by_point[name], source_rows)
