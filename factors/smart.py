"""A per-host "smart" photometric factor: the host's inverse depths live inside the factor.

GTSAM's Python ``CustomFactor`` copies the whole ``Values`` on every call from inside an
optimiser (the team's measured facts about the GTSAM wheel, docs/factors.md), so one factor and one variable per
inverse depth costs O(points x variables) per iteration. :class:`HostPointsFactor` holds all
points hosted in one keyframe, evaluates all their residuals in all targets in one vectorised
pass, eliminates the inverse depths by the Schur complement and hands GTSAM only the pose and
affine blocks of its keys. The optimiser's Values then hold a few dozen variables.

The linearisation itself (weights, robust losses, accumulation over targets, stereo term, depth
prior, Schur complement, back-substitution, safeguarded depth step) is
:class:`factors.host_points.HostPoints`, shared with the hand-rolled window solver; this module is
its GTSAM adapter: keys, ``Values`` -> poses and affines, the whitening below, the cache by state
and the commit of the depths.

The factor's linear part is ``|R dx + e'|^2`` with ``R^T R = H_red``, ``R^T e' = g_red``.
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

import contextlib
import functools
from dataclasses import dataclass
from typing import Iterator, Sequence

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.gtsam_factors import DEFAULT_HUBER_K, DEFAULT_SIGMA_INTENSITY, PythonFactor, _twin_class
from factors.host_points import DepthSystem, HostPoints, HostSamples
from factors.photometric import PATTERN_DSO8, GradientSampler
from gtvo.core.camera import PinholeCamera
from gtvo.core.kernel_threads import map_independent
from gtvo.core.timing import timed
from gtvo.errors import InputError

FloatArray = NDArray[np.float64]


def whitened_system(H: FloatArray, g: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``R`` and ``e`` with ``R^T R = H + reg I`` and ``R^T e = g`` (the whitened linear part of a
    host factor), ``reg = 1e-9 * mean(diag(H))``: a host's reduced system is singular along the
    gauge (moving all its keyframes together changes no residual), which gets this tiny curvature.

    A Cholesky factorisation (``R`` upper triangular); an eigen-decomposition with the eigenvalues
    clamped at ``reg`` when round-off makes ``H`` indefinite beyond ``reg``.
    """
    m = H.shape[0]
    reg = 1e-9 * max(float(np.trace(H)) / m, 1e-12)
    try:
        L = np.linalg.cholesky(H + reg * np.eye(m))
    except np.linalg.LinAlgError:
        evals, evecs = np.linalg.eigh(H)
        evals = np.maximum(evals, reg)
        return (evecs * np.sqrt(evals)).T, (evecs.T @ g) / np.sqrt(evals)
    return L.T, np.linalg.solve(L, g)


class JacobianBudget:
    """How many bytes of cost-pass Jacobians the host factors of one graph may keep together.

    A host factor's cost pass (LM's trial) computes its residuals' Jacobians too and keeps them for
    the linearisation that follows an accepted step (a third of a pass saved). That is about 10 MB
    a host for a KITTI-sized keyframe: fine for a window of 7, not for a log of thousands. A factor
    given a budget keeps its Jacobians only while the budget has room (first come, first kept:
    the factors of one pass keep theirs pass after pass); the others evaluate their cost without
    Jacobians and keep nothing, and their linearisation evaluates the residuals again with them (the
    same values: each point's residuals depend on its own depth only). Results are the same either way.
    """

    def __init__(self, max_bytes: int) -> None:
        if max_bytes < 0:
            raise InputError(f"JacobianBudget: max_bytes must be >= 0, got {max_bytes}")
        self.max_bytes = int(max_bytes)
        self.used = 0

    def reserve(self, nbytes: int) -> bool:
        """Take ``nbytes`` if they fit; True when taken."""
        if self.used + nbytes > self.max_bytes:
            return False
        self.used += nbytes
        return True

    def release(self, nbytes: int) -> None:
        """Give back ``nbytes`` taken by :meth:`reserve`."""
        self.used = max(self.used - nbytes, 0)


@dataclass
class _Linearization:
    x_poses: list[gtsam.Pose3]
    x_affines: list[FloatArray]
    system: DepthSystem


@functools.lru_cache(maxsize=64)
def _unit_noise(dim: int) -> gtsam.noiseModel.Base:
    """``gtsam.noiseModel.Unit.Create(dim)``, one per dimension (immutable: the factors share it)."""
    return gtsam.noiseModel.Unit.Create(dim)


@functools.lru_cache(maxsize=64)
def _column_blocks(n_targets: int, with_affine: bool) -> tuple[NDArray[np.intp], ...]:
    """:meth:`HostPointsFactor._columns` of every target of a factor with ``n_targets`` targets, made
    once per shape (the factors of every solve share them: read, never written)."""
    return tuple(HostPointsFactor._block_columns(t, n_targets, with_affine) for t in range(n_targets))


class HostPointsFactor(PythonFactor):
    """All points hosted in one keyframe, observed in several targets; inverse depths Schur-eliminated.

    Keys, in this order: ``host_key``, ``target_keys...``, then (if given) ``affine_host_key`` and
    ``affine_target_keys...``, then (if given) ``rig_key``. Error dimension M + 1,
    M = 6 (1 + T) (+ 2 (1 + T) with affines) (+ 2 with the rig offset).

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
        rig_key: key of the rig offset ``(delta_x, delta_y)`` (Vector2, px) of the stereo term
            (:func:`factors.photometric.stereo_residuals`' ``offset``), or None (rectified model).
            Needs ``right_image``; it is the factor's last key and the last 2 entries of M.
        jacobian_budget: shared by the host factors of one graph: keep a cost pass's Jacobians for
            the linearisation only while it has room (:class:`JacobianBudget`); None: always keep
            them (the window's few hosts).
        host_samples: the host's :class:`factors.host_points.HostSamples` when the caller keeps them
            (the window, across its solves); None: sampled here.

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
                 prior_inverse_depth: ArrayLike | None = None, rig_key: int | None = None,
                 jacobian_budget: JacobianBudget | None = None, host_samples: HostSamples | None = None) -> None:
        self.target_keys = list(target_keys)
        if not self.target_keys:
            raise InputError("HostPointsFactor needs at least one target")
        if len(target_images) != len(self.target_keys):
            raise InputError(f"HostPointsFactor: {len(self.target_keys)} target keys but "
                             f"{len(target_images)} target images")
        self.with_affine = affine_host_key is not None
        if self.with_affine and (affine_target_keys is None or len(affine_target_keys) != len(self.target_keys)):
            raise InputError("HostPointsFactor: give one affine target key per target with affine_host_key")
        n = np.asarray(pixels, dtype=float).reshape(-1, 2).shape[0]
        d = np.asarray(inverse_depth, dtype=float).reshape(-1)
        if n == 0 or d.shape[0] != n or not np.all(np.isfinite(d)) or np.any(d <= 0):
            raise InputError(f"HostPointsFactor: need N > 0 points with finite positive inverse depths (N={n})")
        #: the linearisation (pure numpy, shared with the hand-rolled window solver)
        self.points = HostPoints(camera, pixels, host_image, target_images, inverse_depth_variance,
                                 d if prior_inverse_depth is None else prior_inverse_depth,
                                 sigma_intensity=sigma_intensity, huber_k=huber_k, pattern=pattern,
                                 depth_prior=depth_prior, with_affine=self.with_affine, right_image=right_image,
                                 baseline=baseline, lambda_stereo=lambda_stereo, stereo_affine=stereo_affine,
                                 rig=rig_key is not None, host_samples=host_samples)
        if rig_key is not None and right_image is None:
            raise InputError("HostPointsFactor: a rig_key needs a right image (the stereo term)")
        self.depths = d.copy()
        self.pose_keys = [host_key] + self.target_keys
        self.affine_keys = ([affine_host_key] + list(affine_target_keys)) if self.with_affine else []
        self.rig_key = rig_key
        self.rig_keys = [] if rig_key is None else [rig_key]
        nt = len(self.target_keys)
        self.dim = 6 * (1 + nt) + (2 * (1 + nt) if self.with_affine else 0) + 2 * len(self.rig_keys)
        self._rig_columns = np.arange(self.dim - 2, self.dim, dtype=np.intp) if self.rig_keys else None
        self._column_blocks = _column_blocks(nt, self.with_affine)
        self._lin: _Linearization | None = None
        self._cached: tuple[FloatArray, list[FloatArray]] | None = None
        self._state_lins: tuple[bytes, list] | None = None  # (state key, lins) of the last evaluation
        self._pose_key: tuple[tuple, bytes] | None = None  # (poses, their part of the state key)
        self._budget = jacobian_budget
        self._reserved = 0  # bytes of self._budget the kept lins hold
        self._trial: tuple[bytes, FloatArray, float] | None = None  # (values, depths, cost) of _safeguarded
        #: the host factors whose residuals a cache miss computes together (:func:`shared_residual_passes`)
        self._group: list | None = None
        self._values_now: gtsam.Values | None = None  # the Values of the evaluation under way (with a group)
        super().__init__(_unit_noise(self.dim + 1), self.pose_keys + self.affine_keys + self.rig_keys)

    # --- state -----------------------------------------------------------------------------
    def _read(self, values: gtsam.Values) -> tuple[list[gtsam.Pose3], list[FloatArray]]:
        """Poses, and the vector variables: affines then (with ``rig_key``) the rig offset."""
        poses = [values.atPose3(k) for k in self.pose_keys]
        affs = [np.asarray(values.atVector(k), dtype=float) for k in self.affine_keys + self.rig_keys]
        return poses, affs

    def _split(self, affs: list[FloatArray]) -> tuple[list[FloatArray], FloatArray | None]:
        """``(affines, rig offset or None)`` of :meth:`_read`'s vector variables."""
        if self.rig_key is None:
            return affs, None
        return affs[:-1], affs[-1]

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
        return lin.system.back_substitute(self._delta(poses, affs))

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
        if self._trial is not None and self._trial[0] == key:
            return self._trial[1], self._trial[2]
        d = self._back_substitution(poses, affs)
        A, offset = self._split(affs)
        lins = self._lins(poses, affs, d)
        c, d_safe, lins = self.points.safeguard(poses, A, lin.system, d, lins, offset,
                                                jacobians=lins[0] is None or lins[0].J_host is not None)
        if d_safe is not d and self._state_lins is not None:  # kept: the merged ones, at their state
            self._state_lins = (self._state(poses, affs, d_safe), lins)
        d = d_safe
        E = float(c.sum())
        self._trial = (key, d, E)
        return d, E

    def depths_at(self, values: gtsam.Values) -> FloatArray:
        """The inverse depths :meth:`commit` would set at ``values``, without committing: the factor
        keeps its linearisation, weights and caches (a linearisation at ``values`` that follows,
        e.g. ``gtsam.Marginals``, reuses the residuals of the cost pass there)."""
        poses, affs = self._read(values)
        return np.array(self._depths_at(poses, affs), dtype=float)

    def take_residuals(self, poses: Sequence[gtsam.Pose3], vectors: Sequence[FloatArray], lins: list) -> None:
        """Take ``lins`` as this factor's residuals at ``poses`` (host first, then the targets) and
        ``vectors`` (the affines, then the rig offset: the factor's vector variables in key order)
        with its current inverse depths: its first evaluation there reuses them instead of a pass.
        They must be what a pass there computes (every target then the stereo term, with
        Jacobians; a caller keeps them across solves, :mod:`gtvo.window.residual_memo`). Ignored
        with a :class:`JacobianBudget` (the budget decides what a factor keeps)."""
        if self._budget is None:
            self._keep((self._state(list(poses), list(vectors), self.depths), lins))

    def kept_residuals(self, values: gtsam.Values, inverse_depth: FloatArray
                       ) -> tuple[list[gtsam.Pose3], list[FloatArray], FloatArray | None, list] | None:
        """``(poses, affines, rig offset or None, residuals)`` of the residuals this factor keeps at
        ``values`` with ``inverse_depth`` (its last evaluation's, when it was there: e.g. at the
        optimum after :meth:`depths_at`), or None when it keeps none there."""
        kept = self._state_lins
        if kept is None:
            return None
        poses, affs = self._read(values)
        if kept[0] != self._state(poses, affs, np.asarray(inverse_depth, dtype=float)):
            return None
        affines, offset = self._split(affs)
        return poses, affines, offset, kept[1]

    def commit(self, values: gtsam.Values) -> FloatArray:
        """Set the inverse depths to those implied at ``values`` (call after optimisation)."""
        poses, affs = self._read(values)
        self.depths = self._depths_at(poses, affs)
        self._lin = None
        self.points.release_weights()
        self._cached = None
        self._keep(None)
        self._trial = None
        return self.depths

    # --- residuals ---------------------------------------------------------------------------
    def _state(self, poses, affs, d) -> bytes:
        """The state as one byte string (cache key: equal bytes, the same residuals): the poses'
        matrices, the vector variables, the inverse depths. The poses' part is made once per set
        of pose objects (:meth:`_read`'s, immutable ``gtsam.Pose3``: one evaluation asks for the key
        of its poses two or three times, with and without depths)."""
        cached = self._pose_key
        if cached is not None and len(cached[0]) == len(poses) and all(a is b for a, b in zip(cached[0], poses)):
            pose_bytes = cached[1]
        else:
            pose_bytes = b"".join([np.asarray(p.matrix(), dtype=float).tobytes() for p in poses])
            self._pose_key = (tuple(poses), pose_bytes)
        parts = [pose_bytes] + [np.asarray(a, dtype=float).tobytes() for a in affs]
        if d is not None:
            parts.append(np.asarray(d, dtype=float).tobytes())
        return b"".join(parts)

    def _lins(self, poses, affs, d, jacobians: bool = False) -> list:
        """Linearisations of every target, then the stereo term (or None), at a state (with
        ``jacobians``: with their Jacobians, else perhaps without).

        One evaluation per state: LM evaluates the cost at a trial state and, when it accepts it,
        linearises at the same state; the cost pass already computes the Jacobians (about a third
        of a pass's time, the bilinear gathers being the rest) so that the linearisation reuses it,
        while the factor's :class:`JacobianBudget` has room; else the cost pass computes no
        Jacobians and keeps nothing, and the linearisation evaluates the state again.
        """
        state = self._state(poses, affs, d)
        if self._state_lins is not None and self._state_lins[0] == state:
            return self._state_lins[1]
        A, offset = self._split(affs)
        if self._group is not None and self._values_now is not None and self._budget is None:
            out = self._group_residuals(self._values_now, poses, A, d, offset)
            self._state_lins = (state, out)
            return out
        nbytes = self._jacobian_bytes()
        keep = self._budget is None or self._budget.reserve(nbytes - self._reserved)
        if keep:
            self._reserved = nbytes if self._budget is not None else 0
        else:
            self._keep(None)
        out = self.points.residuals(poses, A, d, offset=offset, jacobians=keep or jacobians)
        if keep:
            self._state_lins = (state, out)
        return out

    def _pending(self, values: gtsam.Values) -> tuple[bytes, list, list | None, FloatArray, FloatArray | None] | None:
        """``(state, poses, affines, depths, rig offset)`` of the residuals this factor's next
        evaluation at ``values`` computes (the error's and the linearisation's first pass: the
        depths of :meth:`_safeguarded`, or the committed ones before a linearisation), or None when
        its cache holds them."""
        poses, affs = self._read(values)
        if self._lin is None:
            d = self.depths
        else:
            trial = self._trial
            key = self._state(poses, affs, None)
            d = trial[1] if trial is not None and trial[0] == key else self._back_substitution(poses, affs)
        state = self._state(poses, affs, d)
        if self._state_lins is not None and self._state_lins[0] == state:
            return None
        A, offset = self._split(affs)
        return state, poses, A, d, offset

    def _group_residuals(self, values: gtsam.Values, poses: list, A: list | None, d: FloatArray,
                         offset: FloatArray | None) -> list:
        """This factor's residuals and those every other factor of its group will ask for at the
        same ``values`` (:meth:`_pending`), all their calls at once on the kernel threads; the
        others' go into their caches. The numbers are those of one factor at a time (each call is
        a pure function of its state); only when they are computed changes."""
        others = [(g, p) for g in self._group if g.__dict__ is not self.__dict__ for p in [g._pending(values)]
                  if p is not None]
        calls = [self.points.residual_calls(poses, A, d, offset=offset)]
        calls += [g.points.residual_calls(p[1], p[2], p[3], offset=p[4]) for g, p in others]
        flat = map_independent([c for cs in calls for c in cs])
        start = len(calls[0])
        for (g, p), cs in zip(others, calls[1:]):
            g._state_lins = (p[0], flat[start:start + len(cs)])
            start += len(cs)
        return flat[:len(calls[0])]

    def _jacobian_bytes(self) -> int:
        """About what one evaluation's linearisations hold: per point, pattern pixel and target
        the residual, validity, ``J_depth``, warped pixel and host pose and affine Jacobians."""
        n, p = self.points.pixels.shape[0], self.points.pattern.shape[0]
        return n * p * (len(self.target_keys) * (8 * (1 + 1 + 2 + 6 + 2) + 1) + 8 * (1 + 1 + 2 + 2) + 1)

    def _keep(self, kept: tuple[bytes, list] | None) -> None:
        """Set the kept linearisations (None: none; their budget given back)."""
        if kept is None and self._budget is not None and self._reserved:
            self._budget.release(self._reserved)
            self._reserved = 0
        self._state_lins = kept

    def cost(self, values: gtsam.Values, inverse_depth: ArrayLike | None = None) -> float:
        """The true nonlinear cost at ``values`` with the given (default: current) inverse depths."""
        poses, affs = self._read(values)
        d = self.depths if inverse_depth is None else np.asarray(inverse_depth, dtype=float)
        return self._cost(poses, affs, d)

    def _cost(self, poses, affs, d) -> float:
        return float(self.points.point_costs(self._lins(poses, affs, d), d).sum())

    def _columns(self, t: int) -> NDArray[np.intp]:
        """Reduced-state columns of target t's Gauss-Newton block, in :func:`gauss_newton_sums`'
        order: host pose, [host affine,] target pose[, target affine] (the reduced state holds all
        poses first, then all affines)."""
        return self._block_columns(t, len(self.target_keys), self.with_affine)

    @staticmethod
    def _block_columns(t: int, n_targets: int, with_affine: bool) -> NDArray[np.intp]:
        """:meth:`_columns` of target ``t`` of a factor with ``n_targets`` targets."""
        host_pose, target_pose = list(range(6)), list(range(6 * (1 + t), 6 * (2 + t)))
        if not with_affine:
            return np.array(host_pose + target_pose, dtype=np.intp)
        base = 6 * (1 + n_targets)
        host_aff, target_aff = [base, base + 1], [base + 2 * (1 + t), base + 2 * (1 + t) + 1]
        return np.array(host_pose + host_aff + target_pose + target_aff, dtype=np.intp)

    def _linearize(self, poses, affs) -> tuple[FloatArray, FloatArray, float]:
        if self._lin is not None:
            self.depths = self._safeguarded(poses, affs)[0]
        d = self.depths
        H_red = np.zeros((self.dim, self.dim))
        g_red = np.zeros(self.dim)
        system = self.points.linearize(self._lins(poses, affs, d, jacobians=True), d, H_red, g_red, self._column_blocks,
                                       self._rig_columns)
        E = float(system.point_cost.sum())
        self._lin = _Linearization(poses, affs, system)
        self._trial = None  # the safeguard compares against this linearisation's depths now
        return 0.5 * (H_red + H_red.T), g_red, E - system.newton_decrease()

    @timed("linearisation")  # GTSAM's every call of this factor: its cost or its linearisation
    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        if self._group is None:
            return self._evaluate_at(values, H)
        self._values_now = values
        try:
            return self._evaluate_at(values, H)
        finally:
            self._values_now = None

    def _evaluate_at(self, values: gtsam.Values, H: list | None) -> np.ndarray:
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
        R, e_red = whitened_system(H_red, g_red)
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
        n_keys = len(self.pose_keys) + len(self.affine_keys)
        if self.rig_key is not None:
            H[n_keys] = Rfull[:, M - 2:M]
            n_keys += 1
        self._cached = (out.copy(), [np.array(H[i]) for i in range(n_keys)])
        return out


@contextlib.contextmanager
def shared_residual_passes(factors: Sequence[HostPointsFactor]) -> Iterator[None]:
    """Within the block, the host factors of one graph compute their residuals together: when one
    of them misses its cache at a ``Values``, it computes the residuals every factor of the group
    will ask for at those values, all their (host, target) calls at once on the process's kernel
    threads (:func:`gtvo.core.kernel_threads.map_independent`), instead of one host's at a time
    as GTSAM calls them. For whole-graph passes (LM's cost and linearisation, ``gtsam.Marginals``):
    the parallel window's worker groups the LM graph's hosts when it has more than one kernel
    thread (docs/window.md, "Kernel threads in the worker"). The results are those of the factors
    alone, to the bit (a residual is a pure function of its state; a pass that evaluates only some
    factors at most computes the others' in vain). A factor with a :class:`JacobianBudget` (the
    whole-log refinement's) computes its own residuals alone: the budget decides what it keeps.

    The group holds the factors' plain-Python twins (:class:`factors.gtsam_factors.PythonFactor`),
    not the GTSAM objects, and is dropped at the block's end: no reference cycle keeps a factor
    and its images alive after it."""
    group = [_twin_class(type(f))() for f in factors]
    for twin, f in zip(group, factors):
        twin.__dict__ = f.__dict__
        f._group = group
    try:
        yield
    finally:
        for f in factors:
            f._group = None
        group.clear()
