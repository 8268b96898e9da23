"""A per-host "smart" photometric factor: the host's inverse depths live inside the factor.

GTSAM's Python ``CustomFactor`` copies the whole ``Values`` on every call from inside an
optimiser (``/work/shared/notes/dependency-facts.md``), so one factor and one variable per
inverse depth costs O(points x variables) per iteration. :class:`HostPointsFactor` holds all
points hosted in one keyframe, evaluates all their residuals in all targets in one vectorised
pass, eliminates the inverse depths by the Schur complement and hands GTSAM only the pose and
affine blocks of its keys. The optimiser's Values then hold a few dozen variables.

Linearisation at values ``x`` (poses/affines of the keys) and inverse depths ``d``, with the
IRLS weights ``w_n`` (Huber on each point-target pattern norm) and variance weights ``W``::

    H_pp = sum J_p^T wW J_p,  H_pd[n] = sum J_p^T wW J_d,  H_dd[n] = sum wW J_d^2 (+ 1/sigma_prior^2)
    g_p  = sum J_p^T wW r,    g_d[n]  = sum wW J_d r      (+ (d - d_prior)/sigma_prior^2)
    H_red = H_pp - sum_n H_pd H_pd^T / H_dd,    g_red = g_p - sum_n H_pd g_d / H_dd

and the factor's linear part is ``|R dx + e'|^2`` with ``R^T R = H_red``, ``R^T e' = g_red``.
An extra error entry ``c`` with zero Jacobian, ``c^2 = 2E - sum_n g_d^2/H_dd - |e'|^2 >= 0``,
makes the linear model at ``dx`` equal the Gauss-Newton model of the cost with the depths at
their conditional optimum (at ``dx = 0``: E minus the depth-only Newton decrease). ``error(x)``
is the true nonlinear cost at ``x`` with the depths GTSAM's step implies, ``d(x) = d_lin + dd(x)``,
the back-substitution ``dd = -(g_d + H_pd^T (x - x_lin)) / H_dd``, safeguarded per point: a point
whose cost rose above its cost at the linearisation point keeps ``d_lin`` if that costs less at
``x`` (LM's lambda damps only the poses and affines; the undamped depth step raised the cost of
many points near the optimum, so that even ``dx -> 0`` raised the cost and LM ran lambda up to its
bound). The next linearisation at a *different* point
commits ``d(x)``, so the depths follow every accepted step (a linearisation at the same point
again returns the cached system: iSAM2 linearises new factors twice).
:meth:`HostPointsFactor.commit` commits them at the final values after optimisation. Details: docs/factors.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.gtsam_factors import DEFAULT_HUBER_K, DEFAULT_SIGMA_INTENSITY, PythonFactor
from factors.photometric import (PATTERN_DSO8, GradientSampler, gauss_newton_sums, pattern_bearings,
                                 photometric_residuals, point_robust_terms, replace_rows, sample_host, stereo_residuals,
                                 variance_weight)
from gtvo.core.camera import PinholeCamera
from gtvo.errors import InputError

FloatArray = NDArray[np.float64]


@dataclass
class _Linearization:
    x_poses: list[gtsam.Pose3]
    x_affines: list[FloatArray]
    d: FloatArray
    H_pd: FloatArray  # (N, M)
    H_dd: FloatArray  # (N,)
    g_d: FloatArray  # (N,)
    active: NDArray[np.bool_]  # (N,) points with curvature
    point_cost: FloatArray  # (N,) each point's cost at the linearisation point


def keep_cheaper_depths(d: FloatArray, c: FloatArray, lins: list, rows: NDArray[np.intp], d_old: FloatArray,
                        c_old: FloatArray, lins_old: list) -> tuple[FloatArray, FloatArray, list]:
    """The safeguarded depth step's merge: of the points ``rows`` (whose cost at the new depths
    ``d`` rose), those that cost less at their old depth (``c_old``, ``lins_old``: evaluated for
    ``rows`` only) take it back. Returns ``(depths, point costs, linearisations)``; the inputs
    are not modified."""
    keep = np.flatnonzero(c_old < c[rows])
    if not keep.size:
        return d, c, lins
    r = rows[keep]
    d, c = d.copy(), c.copy()
    d[r], c[r] = d_old[r], c_old[keep]
    return d, c, [None if a is None else replace_rows(a, r, b, keep) for a, b in zip(lins, lins_old)]


class HostPointsFactor(PythonFactor):
    """All points hosted in one keyframe, observed in several targets; inverse depths Schur-eliminated.

    Keys, in this order: ``host_key``, ``target_keys...``, then (if given) ``affine_host_key`` and
    ``affine_target_keys...``. Error dimension M + 1, M = 6 (1 + T) (+ 2 (1 + T) with affines).

    Args:
        host_key: the host keyframe's pose key.
        target_keys: pose keys of the frames the points are observed in (T >= 1).
        camera: intrinsics (all images share them).
        pixels: (N, 2) host pixels; inverse_depth (N,) initial inverse depths (> 0).
        host_image: the host image with gradients.
        target_images: one image with gradients per target key.
        inverse_depth_variance: (N,) V used in the weight W (and, with ``depth_prior``, as the
            prior's variance).
        sigma_intensity, huber_k, pattern: as in :class:`factors.gtsam_factors.PhotometricFactor`.
        affine_host_key, affine_target_keys: affine (a, b) keys, or None (all affines fixed at 0).
        depth_prior: keep a prior ``(d - d_init)^2 / V`` on each inverse depth (e.g. the stereo
            estimate), which also fixes depths of points seen in no target.
        right_image, baseline, lambda_stereo: add the notes' stereo energy ``lambda E_s`` of the
            host frame (``factors.photometric.stereo_residuals``, the residual of
            :class:`factors.gtsam_factors.StereoFactor`); it involves only the depths, so it enters
            ``H_dd``, ``g_d`` and the cost.
        prior_inverse_depth: the depth prior's mean (default: ``inverse_depth``); pass the original
            stereo estimate when rebuilding a factor (new targets) from ``old.depths``.
        stereo_affine: the right image's brightness ``(a, b)`` relative to the host's left image,
            held fixed (the stereo residual is ``I_R(p') - b - exp(a) I_L(p)``).

    The variance weights W are frozen at the first linearisation of an optimisation run and
    released by :meth:`commit` (so the next run re-evaluates them): with W moving with the
    state the Gauss-Newton model would not match the cost that LM compares, and LM stalls.
    """

    def __init__(self, host_key: int, target_keys: Sequence[int], camera: PinholeCamera, pixels: ArrayLike,
                 inverse_depth: ArrayLike, host_image: GradientSampler, target_images: Sequence[GradientSampler],
                 inverse_depth_variance: ArrayLike | float = 1e-4,
                 sigma_intensity: float = DEFAULT_SIGMA_INTENSITY, huber_k: float | None = DEFAULT_HUBER_K,
                 affine_host_key: int | None = None, affine_target_keys: Sequence[int] | None = None,
                 depth_prior: bool = True, pattern: ArrayLike = PATTERN_DSO8,
                 right_image: GradientSampler | None = None, baseline: float | None = None,
                 lambda_stereo: float = 1.0, stereo_affine: ArrayLike = (0.0, 0.0),
                 prior_inverse_depth: ArrayLike | None = None) -> None:
        self.target_keys = list(target_keys)
        if not self.target_keys:
            raise InputError("HostPointsFactor needs at least one target")
        if len(target_images) != len(self.target_keys):
            raise InputError(f"HostPointsFactor: {len(self.target_keys)} target keys but "
                             f"{len(target_images)} target images")
        self.with_affine = affine_host_key is not None
        if self.with_affine and (affine_target_keys is None or len(affine_target_keys) != len(self.target_keys)):
            raise InputError("HostPointsFactor: give one affine target key per target with affine_host_key")
        self.camera = camera
        self.pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
        n = self.pixels.shape[0]
        d = np.asarray(inverse_depth, dtype=float).reshape(-1)
        if n == 0 or d.shape[0] != n or not np.all(np.isfinite(d)) or np.any(d <= 0):
            raise InputError(f"HostPointsFactor: need N > 0 points with finite positive inverse depths (N={n})")
        self.variance = np.broadcast_to(np.asarray(inverse_depth_variance, dtype=float), (n,)).copy()
        if depth_prior and not np.all(self.variance > 0):
            raise InputError("HostPointsFactor: a depth prior needs positive inverse-depth variances")
        self.pattern = np.asarray(pattern, dtype=float).reshape(-1, 2)
        self.host_intensity, self.host_valid = sample_host(host_image, self.pixels, self.pattern)
        self.bearings = pattern_bearings(camera, self.pixels, self.pattern)  # fixed: host pixels only
        self.target_images = list(target_images)
        self.sigma = float(sigma_intensity)
        self.huber_k = huber_k
        self.depth_prior = bool(depth_prior)
        self.d_prior = d.copy() if prior_inverse_depth is None else \
            np.asarray(prior_inverse_depth, dtype=float).reshape(-1).copy()
        if self.d_prior.shape[0] != n or not np.all(np.isfinite(self.d_prior)):
            raise InputError(f"HostPointsFactor: prior_inverse_depth must hold {n} finite values")
        self.depths = d.copy()
        self.pose_keys = [host_key] + self.target_keys
        self.affine_keys = ([affine_host_key] + list(affine_target_keys)) if self.with_affine else []
        nt = len(self.target_keys)
        self.dim = 6 * (1 + nt) + (2 * (1 + nt) if self.with_affine else 0)
        self.right_image = right_image
        if right_image is not None:
            if baseline is None or not (np.isfinite(baseline) and baseline > 0):
                raise InputError(f"HostPointsFactor: a stereo term needs a positive baseline, got {baseline!r}")
            if not (np.isfinite(lambda_stereo) and lambda_stereo > 0):
                raise InputError(f"HostPointsFactor: lambda_stereo must be positive, got {lambda_stereo!r}")
        self.baseline = None if baseline is None else float(baseline)
        self.lambda_stereo = float(lambda_stereo)
        self.stereo_affine = np.asarray(stereo_affine, dtype=float).reshape(2)
        self._lin: _Linearization | None = None
        self._W: list[FloatArray] | None = None
        self._cached: tuple[FloatArray, list[FloatArray]] | None = None
        self._state_lins: tuple[FloatArray, list] | None = None  # (state, lins) of the last evaluation
        self._trial: tuple[FloatArray, FloatArray, float] | None = None  # (values, depths, cost) of _safeguarded
        super().__init__(gtsam.noiseModel.Unit.Create(self.dim + 1), self.pose_keys + self.affine_keys)

    # --- state -----------------------------------------------------------------------------
    def _read(self, values: gtsam.Values) -> tuple[list[gtsam.Pose3], list[FloatArray]]:
        poses = [values.atPose3(k) for k in self.pose_keys]
        affs = [np.asarray(values.atVector(k), dtype=float) for k in self.affine_keys]
        return poses, affs

    def _delta(self, poses: list[gtsam.Pose3], affs: list[FloatArray]) -> FloatArray:
        lin = self._lin
        assert lin is not None
        dx = [lin.x_poses[i].localCoordinates(p) for i, p in enumerate(poses)]
        dx += [a - lin.x_affines[i] for i, a in enumerate(affs)]
        return np.concatenate(dx)

    def _back_substitution(self, poses: list[gtsam.Pose3], affs: list[FloatArray]) -> FloatArray:
        """Inverse depths implied by the last linearisation's back-substitution at these values."""
        lin = self._lin
        assert lin is not None
        dx = self._delta(poses, affs)
        step = np.zeros_like(lin.d)
        a = lin.active
        step[a] = -(lin.g_d[a] + lin.H_pd[a] @ dx) / lin.H_dd[a]
        return np.maximum(lin.d + step, 0.1 * lin.d)  # keep d > 0: LM rejects such far steps anyway

    def _depths_at(self, poses: list[gtsam.Pose3], affs: list[FloatArray]) -> FloatArray:
        """The inverse depths that go with these values (:meth:`_safeguarded`)."""
        if self._lin is None:
            return self.depths
        return self._safeguarded(poses, affs)[0]

    def _safeguarded(self, poses: list[gtsam.Pose3], affs: list[FloatArray]) -> tuple[FloatArray, float]:
        """The inverse depths that go with these values and the cost there: the back-substitution
        ``d(x)``, except for points whose cost rose above their cost at the linearisation point and
        that cost less at their linearisation depth, which keep it (module docstring)."""
        lin = self._lin
        assert lin is not None
        key = self._state(poses, affs, None)
        if self._trial is not None and np.array_equal(self._trial[0], key):
            return self._trial[1], self._trial[2]
        d = self._back_substitution(poses, affs)
        c, lins = self._point_costs(poses, affs, d)
        rows = np.flatnonzero(c > lin.point_cost)
        if rows.size:
            lins_old = self._residuals(poses, affs, lin.d, rows)
            d_new = d
            d, c, lins = keep_cheaper_depths(d, c, lins, rows, lin.d, self._losses(lins_old, lin.d, rows), lins_old)
            if d is not d_new:
                self._state_lins = (self._state(poses, affs, d), lins)
        E = float(c.sum())
        self._trial = (key, d, E)
        return d, E

    def commit(self, values: gtsam.Values) -> FloatArray:
        """Set the inverse depths to those implied at ``values`` (call after optimisation)."""
        poses, affs = self._read(values)
        self.depths = self._depths_at(poses, affs)
        self._lin = None
        self._W = None
        self._cached = None
        self._state_lins = None
        self._trial = None
        return self.depths

    # --- residuals ---------------------------------------------------------------------------
    @staticmethod
    def _state(poses, affs, d) -> FloatArray:
        """The state as one vector (cache key)."""
        parts = [np.concatenate([p.matrix().ravel() for p in poses])] + [np.asarray(a, dtype=float) for a in affs]
        return np.concatenate(parts + ([] if d is None else [d]))

    def _lins(self, poses, affs, d) -> list:
        """Linearisations (with Jacobians) of every target, then the stereo term (or None), at a state.

        One evaluation per state: LM evaluates the cost at a trial state and, when it accepts it,
        linearises at the same state; the cost pass already computes the Jacobians (about a third
        of a pass's time, the bilinear gathers being the rest) so that the linearisation reuses it.
        """
        state = self._state(poses, affs, d)
        if self._state_lins is not None and np.array_equal(self._state_lins[0], state):
            return self._state_lins[1]
        out = self._residuals(poses, affs, d)
        self._state_lins = (state, out)
        return out

    def _residuals(self, poses, affs, d, rows: NDArray[np.intp] | None = None) -> list:
        """Linearisations of every target, then the stereo term (or None), of all points or of the
        points ``rows`` (``d`` is always the full (N,) vector); not cached."""
        sel = slice(None) if rows is None else rows
        Ih, hv, px, f, ds = self.host_intensity[sel], self.host_valid[sel], self.pixels[sel], self.bearings[sel], d[sel]
        ah = affs[0] if self.with_affine else np.zeros(2)
        out: list = []
        for t, img in enumerate(self.target_images):
            at = affs[1 + t] if self.with_affine else np.zeros(2)
            out.append(photometric_residuals(self.camera, Ih, hv, px, ds, poses[0], poses[1 + t], img, ah, at,
                                             self.pattern, jacobians=True, host_jacobians=True, bearings=f))
        out.append(None if self.right_image is None else
                   stereo_residuals(self.camera, self.baseline, Ih, hv, px, ds, self.right_image, (0.0, 0.0),
                                    self.stereo_affine, self.pattern, jacobians=False, bearings=f))
        return out

    def _robust(self, W: FloatArray, r: FloatArray) -> tuple[FloatArray, FloatArray]:
        return point_robust_terms(W, r, self.huber_k)

    def _weights(self, lins: list) -> list[FloatArray]:
        """W per target (then stereo): frozen at the first evaluation of a run (class docstring)."""
        if self._W is None:
            W = [variance_weight(lin.J_depth, self.variance, self.sigma) for lin in lins[:-1]]
            if lins[-1] is not None:
                W.append(self.lambda_stereo * variance_weight(lins[-1].J_depth, self.variance, self.sigma))
            self._W = W
        return self._W

    def _target_terms(self, poses, affs, d) -> list[tuple]:
        """Per target: ``(linearisation, W, Huber IRLS weights, loss)``."""
        lins = self._lins(poses, affs, d)
        Ws = self._weights(lins)
        return [(lin, Ws[t], *self._robust(Ws[t], lin.residual)) for t, lin in enumerate(lins[:-1])]

    def _stereo_term(self, d: FloatArray, poses=None, affs=None):
        """The stereo residuals of the host frame: (linearisation, lambda W, Huber weight, loss) or None."""
        if self.right_image is None:
            return None
        lins = self._lins(poses, affs, d)
        Ws = self._weights(lins)
        w, loss = self._robust(Ws[-1], lins[-1].residual)
        return lins[-1], Ws[-1], w, loss

    def cost(self, values: gtsam.Values, inverse_depth: ArrayLike | None = None) -> float:
        """The true nonlinear cost at ``values`` with the given (default: current) inverse depths."""
        poses, affs = self._read(values)
        d = self.depths if inverse_depth is None else np.asarray(inverse_depth, dtype=float)
        return self._cost(poses, affs, d)

    def _cost(self, poses, affs, d) -> float:
        return float(self._point_costs(poses, affs, d)[0].sum())

    def _point_costs(self, poses, affs, d) -> tuple[FloatArray, list]:
        """Each point's cost (N,) at a state, and the linearisations it came from."""
        lins = self._lins(poses, affs, d)
        return self._losses(lins, d), lins

    def _losses(self, lins: list, d: FloatArray, rows: NDArray[np.intp] | None = None) -> FloatArray:
        """Each point's cost from its linearisations: robust photometric and stereo losses and the
        depth prior (``rows``: ``lins`` hold only these points; W must be frozen already)."""
        sel = slice(None) if rows is None else rows
        assert rows is None or self._W is not None
        Ws = self._weights(lins)
        c = np.zeros(d.shape[0] if rows is None else rows.size)
        for W, lin in zip(Ws, lins):
            c += self._robust(W[sel], lin.residual)[1]
        if self.depth_prior:
            c += 0.5 * (d[sel] - self.d_prior[sel]) ** 2 / self.variance[sel]
        return c

    def _columns(self, t: int) -> NDArray[np.intp]:
        """Reduced-state columns of target t's Gauss-Newton block, in :func:`gauss_newton_sums`'
        order: host pose, [host affine,] target pose[, target affine] (the reduced state holds all
        poses first, then all affines)."""
        host_pose, target_pose = list(range(6)), list(range(6 * (1 + t), 6 * (2 + t)))
        if not self.with_affine:
            return np.array(host_pose + target_pose, dtype=np.intp)
        base = 6 * (1 + len(self.target_keys))
        host_aff, target_aff = [base, base + 1], [base + 2 * (1 + t), base + 2 * (1 + t) + 1]
        return np.array(host_pose + host_aff + target_pose + target_aff, dtype=np.intp)

    def _linearize(self, poses, affs) -> tuple[FloatArray, FloatArray, float]:
        if self._lin is not None:
            self.depths = self._safeguarded(poses, affs)[0]
        d = self.depths
        n, M = d.shape[0], self.dim
        H_pp = np.zeros((M, M))
        g_p = np.zeros(M)
        H_pd = np.zeros((n, M))
        H_dd = np.zeros(n)
        g_d = np.zeros(n)
        c_pt = np.zeros(n)
        for t, (lin, W, w, loss) in enumerate(self._target_terms(poses, affs, d)):
            c_pt += loss
            H_t, g_t, H_pd_t, H_dd_t, g_d_t = gauss_newton_sums(lin, W * w[:, None], self.with_affine)
            cols = self._columns(t)
            H_pp[np.ix_(cols, cols)] += H_t
            g_p[cols] += g_t
            H_pd[:, cols] += H_pd_t
            H_dd += H_dd_t
            g_d += g_d_t
        st = self._stereo_term(d, poses, affs)
        if st is not None:
            lin, W, w, loss = st
            ww = W * w[:, None]
            H_dd += np.sum(ww * lin.J_depth ** 2, axis=1)
            g_d += np.sum(ww * lin.J_depth * lin.residual, axis=1)
            c_pt += loss
        if self.depth_prior:
            H_dd += 1.0 / self.variance
            g_d += (d - self.d_prior) / self.variance
            c_pt += 0.5 * (d - self.d_prior) ** 2 / self.variance
        E = float(c_pt.sum())
        active = H_dd > 1e-12 * max(float(H_dd.max()), 1e-300)
        Hdd_s = np.where(active, H_dd, 1.0)
        L = H_pd[active] / Hdd_s[active, None]
        H_red = H_pp - L.T @ H_pd[active]
        g_red = g_p - L.T @ g_d[active]
        self._lin = _Linearization(poses, affs, d.copy(), H_pd, Hdd_s, g_d, active, c_pt)
        self._trial = None  # the safeguard compares against this linearisation's depths now
        depth_decrease = 0.5 * float(np.sum(g_d[active] ** 2 / Hdd_s[active]))
        return 0.5 * (H_red + H_red.T), g_red, E - depth_decrease

    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        poses, affs = self._read(values)
        if H is None:
            E = self._safeguarded(poses, affs)[1] if self._lin is not None else self._cost(poses, affs, self.depths)
            out = np.zeros(self.dim + 1)
            out[-1] = np.sqrt(2.0 * max(E, 0.0))
            return out
        if self._lin is not None and self._cached is not None and np.abs(self._delta(poses, affs)).max() <= 1e-12:
            out, blocks = self._cached  # same point again (iSAM2 linearises new factors twice): no new commit
            for i, b in enumerate(blocks):
                H[i] = b
            return out.copy()
        H_red, g_red, E = self._linearize(poses, affs)  # E: the model's value at dx = 0
        M = self.dim
        reg = 1e-9 * max(float(np.trace(H_red)) / M, 1e-12)
        evals, evecs = np.linalg.eigh(H_red)
        evals = np.maximum(evals, reg)  # PSD up to round-off; gauge directions get a tiny curvature
        R = (evecs * np.sqrt(evals)).T  # R^T R = H_red (regularised)
        e_red = (evecs.T @ g_red) / np.sqrt(evals)  # R^T e_red = g_red
        c2 = max(2.0 * E - float(e_red @ e_red), 0.0)
        out = np.concatenate([e_red, [np.sqrt(c2)]])
        Rfull = np.vstack([R, np.zeros((1, M))])
        nt = len(self.target_keys)
        for i in range(1 + nt):
            H[i] = Rfull[:, 6 * i:6 * (i + 1)]
        if self.with_affine:
            base = 6 * (1 + nt)
            for i in range(1 + nt):
                H[1 + nt + i] = Rfull[:, base + 2 * i:base + 2 * (i + 1)]
        self._cached = (out.copy(), [np.array(H[i]) for i in range(len(self.pose_keys) + len(self.affine_keys))])
        return out
