"""Sliding-window joint optimisation of keyframe poses, affine brightness and inverse depths.

A window holds the last ``N`` keyframes (default 7). Each keyframe hosts its points (pixels,
inverse depths ``d`` and variances ``V`` from stereo or an RGB-D sensor); the cost is

    E = sum_h [ sum_{t in targets(h)} sum_n rho(|sqrt(W) r_{n,h->t}|)      (photometric, factors.photometric)
                + sum_n rho(|sqrt(lambda W) r^stereo_n|)                   (stereo energy, right image)
                + sum_n (d_n - d_n^0)^2 / (2 V_n) ]                         (depth prior: RGB-D only)
        + sum_k |(a_k, b_k) - (a_k^0, b_k^0)|^2_Sigma_affine / 2            (weak affine priors)
        + sum_k |v_{k+1,k+2} - v_{k,k+1}|^2_Sigma_acc / 2                  (motion smoothness)
        + gauge prior on the oldest keyframe (pose and affine)  OR  the marginalisation prior

(the motion term: a :class:`factors.gtsam_factors.ConstantVelocityFactor` on every three
consecutive keyframes with timestamps, ``v`` their body-frame velocity twists, sigmas the
``acceleration_sigma`` times the time between the two velocities) over the keyframes' poses
``x_k`` (``T_world_cam``, GTSAM Pose3, right perturbation), affine
brightness ``(a_k, b_k)`` and all inverse depths. ``targets(h)``: the other keyframes of the
window into which at least ``min_visible_points`` / ``min_visible_fraction`` of the host's points
project (checked by projection at the window's starting state). Two solvers minimise the same E:

* :func:`solve_gtsam`: one :class:`factors.smart.HostPointsFactor` per host (depths
  Schur-eliminated inside the factor), priors as GTSAM factors, the marginalisation prior as
  ``gtsam.LinearContainerFactor``; solved by ``gtsam.LevenbergMarquardtOptimizer``.
* :func:`solve_handrolled`: Levenberg-Marquardt on the reduced camera system (poses + affines)
  assembled in numpy from the kernels of :mod:`factors.photometric`, inverse depths eliminated by
  the Schur complement and recovered by back-substitution.

:class:`SlidingWindowOptimizer` keeps the window: :meth:`~SlidingWindowOptimizer.add_keyframe`
marginalises the oldest keyframe (and the points it hosts) when the window is full: the factors
touching it are linearised at the current estimate, it is eliminated
(``GaussianFactorGraph.eliminatePartialMultifrontal``) and the marginal on the remaining keyframes
is kept as a prior with a fixed linearisation point. Residuals of other hosts' points in the
leaving keyframe are dropped (as DSO does). Details and the consistency choice: docs/window.md.

``WindowConfig(backend="fixed_lag")`` hands the window to ``gtsam.IncrementalFixedLagSmoother``
instead (keyframe sequence number as timestamp, lag ``size - 0.5``): the smoother marginalises
leaving keyframes with their host factor (depths frozen in the marginal); docs/window.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Literal, Sequence

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.gtsam_factors import DEFAULT_HUBER_K, DEFAULT_SIGMA_INTENSITY, ConstantVelocityFactor
from factors.photometric import (PATTERN_DSO8, PATTERN_SINGLE, GradientImage, gauss_newton_sums, pattern_bearings,
                                 photometric_residuals, point_robust_terms, sample_host, stereo_residuals, variance_weight)
from factors.smart import HostPointsFactor, keep_cheaper_depths
from gtvo.core.camera import MIN_DEPTH, PinholeCamera
from gtvo.errors import InputError

FloatArray = NDArray[np.float64]
WindowSolverName = Literal["gtsam", "handrolled"]


def pose_key(frame_index: int) -> int:
    """GTSAM key of a keyframe's pose (``x<frame index>``)."""
    return gtsam.symbol("x", int(frame_index))


def affine_key(frame_index: int) -> int:
    """GTSAM key of a keyframe's affine brightness ``(a, b)`` (``a<frame index>``)."""
    return gtsam.symbol("a", int(frame_index))


@dataclass(frozen=True)
class WindowConfig:
    """Settings of the window (defaults follow DSO where DSO has one).

    Attributes:
        size: keyframes in the window (DSO: 7).
        sigma_intensity, huber_k, pattern: the photometric weight ``W``, the Huber threshold on a
            point's whitened pattern norm and the residual pattern (the factors' defaults: 8 grey
            levels, k = 3, DSO's 8-pixel pattern).
        lambda_stereo: weight of the host's stereo energy ``lambda E_s`` (the notes'
            ``E = E_d + lambda E_s``); 1 treats a left-right residual like a temporal one: both
            compare two images of the same sensor type with the same noise.
        affine_sigma: ``(sigma_a, sigma_b)`` of the prior of each keyframe's affine brightness
            around its tracked value. DSO without photometric calibration leaves ``(a, b)`` free;
            (1.0 log gain, 100 grey levels) is a weak prior that only keeps the system regular.
        acceleration_sigma: ``(angular rad/s^2, linear m/s^2)`` of the motion-smoothness prior, a
            :class:`factors.gtsam_factors.ConstantVelocityFactor` on every three consecutive
            keyframes that have timestamps; None: no motion prior. The defaults are weak (a car
            brakes at up to ~8 m/s^2, a hand-held camera turns faster): with images that fix the
            poses the prior moves nothing; it keeps a window defined when they do not.
        gauge_sigma: sigma (rad, m; log gain, grey levels) of the gauge prior that fixes the oldest
            keyframe's pose and affine while no marginalisation prior exists.
        min_visible_points, min_visible_fraction: a keyframe is a target of a host when at least
            this many (and this fraction) of the host's points project into it, in front of it.
        max_iterations: LM iterations per window optimisation (DSO allows up to 6 per new keyframe;
            on KITTI 4-6 moved the ATE by < 1 mm for 25-45 % more time: docs/benchmarks.md).
        relative_tolerance: stop when an iteration lowers the cost by less than this fraction.
        marginalize: keep leaving keyframes' information as a prior (False: simply drop them).
        backend: ``"lm"``: each window optimised by a solver (:func:`solve_gtsam` or
            :func:`solve_handrolled`) and leaving keyframes marginalised by :func:`marginalize`;
            ``"fixed_lag"``: a ``gtsam.IncrementalFixedLagSmoother`` (iSAM2) holds the window,
            the keyframe's sequence number as timestamp and lag ``size - 0.5``, and marginalises
            leaving keyframes itself (docs/window.md, "Fixed-lag backend").
    """

    size: int = 7
    sigma_intensity: float = DEFAULT_SIGMA_INTENSITY
    huber_k: float | None = DEFAULT_HUBER_K
    pattern: FloatArray = field(default_factory=lambda: PATTERN_DSO8.copy())
    lambda_stereo: float = 1.0
    affine_sigma: tuple[float, float] = (1.0, 100.0)
    acceleration_sigma: tuple[float, float] | None = (1.0, 2.0)
    gauge_sigma: float = 1e-6
    min_visible_points: int = 30
    min_visible_fraction: float = 0.1
    max_iterations: int = 3
    relative_tolerance: float = 1e-4
    marginalize: bool = True
    backend: Literal["lm", "fixed_lag"] = "lm"

    def __post_init__(self) -> None:
        if self.backend not in ("lm", "fixed_lag"):
            raise InputError(f"unknown window backend {self.backend!r}: use 'lm' or 'fixed_lag'")
        if int(self.size) < 2:
            raise InputError(f"window size must be >= 2, got {self.size}")
        if not (self.lambda_stereo > 0 and np.isfinite(self.lambda_stereo)):
            raise InputError(f"lambda_stereo must be positive, got {self.lambda_stereo!r}")
        if not all(s > 0 and np.isfinite(s) for s in self.affine_sigma):
            raise InputError(f"affine_sigma must be positive, got {self.affine_sigma!r}")
        acc = self.acceleration_sigma
        if acc is not None and (len(acc) != 2 or not all(s > 0 and np.isfinite(s) for s in acc)):
            raise InputError(f"acceleration_sigma must be two positive numbers or None, got {acc!r}")
        if self.max_iterations < 1:
            raise InputError(f"max_iterations must be >= 1, got {self.max_iterations}")


@dataclass
class WindowKeyframe:
    """One keyframe of the window: its state and its hosted points.

    Attributes:
        index: frame index (the keys are ``x<index>``, ``a<index>``).
        pose: ``T_world_cam`` of the left camera.
        affine: ``(a, b)`` of its left image (window-wide brightness reference).
        image: left image with gradients.
        pixels, inverse_depth, variance: its points (N, 2), (N,), (N,).
        right: right image with gradients (stereo energy), or None.
        depth_prior: keep ``(d - prior_inverse_depth)^2 / V`` (RGB-D: the sensor's depth).
        prior_inverse_depth: the depth prior's mean (default: the initial inverse depths).
        affine_prior: mean of the affine prior (default: the initial affine).
        stereo_affine: the right image's ``(a, b)`` relative to the left one (held fixed).
        timestamp: capture time (s); keyframes without one get no motion-smoothness prior.
    """

    index: int
    pose: gtsam.Pose3
    affine: FloatArray
    image: GradientImage
    pixels: FloatArray
    inverse_depth: FloatArray
    variance: FloatArray
    right: GradientImage | None = None
    depth_prior: bool = False
    prior_inverse_depth: FloatArray | None = None
    affine_prior: FloatArray | None = None
    stereo_affine: FloatArray = field(default_factory=lambda: np.zeros(2))
    timestamp: float | None = None

    def __post_init__(self) -> None:
        self.pixels = np.asarray(self.pixels, dtype=float).reshape(-1, 2)
        n = self.pixels.shape[0]
        self.inverse_depth = np.asarray(self.inverse_depth, dtype=float).reshape(-1).copy()
        self.variance = np.broadcast_to(np.asarray(self.variance, dtype=float), (n,)).copy()
        self.affine = np.asarray(self.affine, dtype=float).reshape(2).copy()
        if n == 0 or self.inverse_depth.shape[0] != n:
            raise InputError(f"keyframe {self.index}: need N > 0 points with one inverse depth each")
        if not (np.all(np.isfinite(self.inverse_depth)) and np.all(self.inverse_depth > 0)
                and np.all(np.isfinite(self.variance)) and np.all(self.variance > 0)):
            raise InputError(f"keyframe {self.index}: inverse depths and variances must be finite and > 0")
        if self.right is None and not self.depth_prior:
            raise InputError(f"keyframe {self.index}: without a right image the depths need a depth prior")
        if self.prior_inverse_depth is None:
            self.prior_inverse_depth = self.inverse_depth.copy()
        if self.affine_prior is None:
            self.affine_prior = self.affine.copy()
        self.stereo_affine = np.asarray(self.stereo_affine, dtype=float).reshape(2)

    def __len__(self) -> int:
        return int(self.pixels.shape[0])


@dataclass
class MarginalPrior:
    """The information of marginalised keyframes on the remaining ones, a quadratic in

    ``delta = x_lin.localCoordinates(x)`` (per key) with a fixed linearisation point ``x_lin``::

        E_m(x) = 0.5 delta^T H delta - eta^T delta + 0.5 f

    (GTSAM's augmented-Hessian form). ``factors`` are the same quadratic as GTSAM linear factors.
    """

    keys: list[int]
    dims: list[int]
    H: FloatArray
    eta: FloatArray
    f: float
    linearization_point: gtsam.Values
    factors: gtsam.GaussianFactorGraph

    def delta(self, values: gtsam.Values) -> FloatArray:
        """``x_lin.localCoordinates(x)`` stacked over :attr:`keys`."""
        return np.asarray(self.linearization_point.localCoordinates(_subset(values, self.keys)).vector(
            list(self.keys)), dtype=float)

    def cost(self, values: gtsam.Values) -> float:
        """``E_m`` at ``values``."""
        dl = self.delta(values)
        return float(0.5 * dl @ self.H @ dl - self.eta @ dl + 0.5 * self.f)

    def nonlinear_factors(self) -> list[gtsam.LinearContainerFactor]:
        """The prior as ``gtsam.LinearContainerFactor`` s (fixed linearisation point)."""
        return [gtsam.LinearContainerFactor(self.factors.at(i), self.linearization_point)
                for i in range(self.factors.size())]


@dataclass
class WindowResult:
    """Outcome of one window optimisation.

    Attributes:
        solver: which solver ran.
        initial_cost, cost: E before and after.
        iterations: LM iterations.
        seconds: wall time.
        n_residuals: point-target pairs in the photometric terms.
    """

    solver: str
    initial_cost: float
    cost: float
    iterations: int
    seconds: float
    n_residuals: int


# ----------------------------------------------------------------------------------------------
# the problem shared by both solvers


def _ordering(keys: Sequence[int]) -> gtsam.Ordering:
    o = gtsam.Ordering()
    for k in keys:
        o.push_back(k)
    return o


def _subset(values: gtsam.Values, keys: Sequence[int]) -> gtsam.Values:
    out = gtsam.Values()
    for k in keys:
        if gtsam.Symbol(k).chr() == ord("x"):
            out.insert(k, values.atPose3(k))
        else:
            out.insert(k, values.atVector(k))
    return out


def window_values(keyframes: Sequence[WindowKeyframe]) -> gtsam.Values:
    """The keyframes' poses and affines as GTSAM ``Values``."""
    v = gtsam.Values()
    for kf in keyframes:
        v.insert(pose_key(kf.index), kf.pose)
        v.insert(affine_key(kf.index), kf.affine)
    return v


def visible_targets(camera: PinholeCamera, keyframes: Sequence[WindowKeyframe], config: WindowConfig
                    ) -> list[list[int]]:
    """For each host (position in ``keyframes``), the positions of the keyframes that see its points.

    A point counts as seen when it projects in front of the target and inside its image with a
    2-pixel border; a target needs ``min_visible_points`` and ``min_visible_fraction`` of them.
    """
    out: list[list[int]] = []
    for h, kh in enumerate(keyframes):
        X = camera.backproject_inverse_depth(kh.pixels, kh.inverse_depth)
        Th = kh.pose.matrix()
        Xw = X @ Th[:3, :3].T + Th[:3, 3]
        ts: list[int] = []
        for t, kt in enumerate(keyframes):
            if t == h:
                continue
            Tt = kt.pose.inverse().matrix()
            Xt = Xw @ Tt[:3, :3].T + Tt[:3, 3]
            front = Xt[:, 2] > MIN_DEPTH
            z = np.where(front, Xt[:, 2], 1.0)
            u = camera.fx * Xt[:, 0] / z + camera.cx
            v = camera.fy * Xt[:, 1] / z + camera.cy
            inside = front & (u >= 2) & (u <= camera.width - 3) & (v >= 2) & (v <= camera.height - 3)
            n = int(np.count_nonzero(inside))
            if n >= config.min_visible_points and n >= config.min_visible_fraction * len(kh):
                ts.append(t)
        out.append(ts)
    return out


def _gauge_noise(config: WindowConfig, dim: int) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Isotropic.Sigma(dim, config.gauge_sigma)


def motion_factors(keyframes: Sequence[WindowKeyframe], config: WindowConfig
                   ) -> list[tuple[int, ConstantVelocityFactor]]:
    """The motion-smoothness prior: ``(k, factor)`` for every three consecutive keyframes
    ``k, k+1, k+2`` (positions) with increasing timestamps (none when ``acceleration_sigma`` is None)."""
    if config.acceleration_sigma is None:
        return []
    out = []
    for k in range(len(keyframes) - 2):
        a, b, c = keyframes[k], keyframes[k + 1], keyframes[k + 2]
        if a.timestamp is None or b.timestamp is None or c.timestamp is None:
            continue
        dt_prev, dt_next = b.timestamp - a.timestamp, c.timestamp - b.timestamp
        if dt_prev > 0 and dt_next > 0:
            out.append((k, ConstantVelocityFactor(pose_key(a.index), pose_key(b.index), pose_key(c.index),
                                                  dt_prev, dt_next, *config.acceleration_sigma)))
    return out


def prior_factors(keyframes: Sequence[WindowKeyframe], config: WindowConfig, with_gauge: bool
                  ) -> gtsam.NonlinearFactorGraph:
    """Affine priors of every keyframe, and (``with_gauge``) the gauge prior on the oldest."""
    g = gtsam.NonlinearFactorGraph()
    aff_noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(config.affine_sigma, dtype=float))
    for kf in keyframes:
        g.add(gtsam.PriorFactorVector(affine_key(kf.index), np.asarray(kf.affine_prior, dtype=float), aff_noise))
    if with_gauge and keyframes:
        k0 = keyframes[0]
        g.add(gtsam.PriorFactorPose3(pose_key(k0.index), k0.pose, _gauge_noise(config, 6)))
        g.add(gtsam.PriorFactorVector(affine_key(k0.index), k0.affine.copy(), _gauge_noise(config, 2)))
    return g


def host_factor(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe], h: int,
                targets: Sequence[int], config: WindowConfig) -> HostPointsFactor:
    """The :class:`HostPointsFactor` of host ``keyframes[h]`` observed in ``targets`` (positions)."""
    kh = keyframes[h]
    return HostPointsFactor(
        pose_key(kh.index), [pose_key(keyframes[t].index) for t in targets], camera, kh.pixels,
        kh.inverse_depth, kh.image, [keyframes[t].image for t in targets], kh.variance,
        sigma_intensity=config.sigma_intensity, huber_k=config.huber_k, affine_host_key=affine_key(kh.index),
        affine_target_keys=[affine_key(keyframes[t].index) for t in targets], depth_prior=kh.depth_prior,
        pattern=config.pattern, right_image=kh.right, baseline=baseline if kh.right is not None else None,
        lambda_stereo=config.lambda_stereo, stereo_affine=kh.stereo_affine,
        prior_inverse_depth=kh.prior_inverse_depth)


def estimate_stereo_affine(camera: PinholeCamera, baseline: float, left: GradientImage, right: GradientImage,
                           pixels: ArrayLike, inverse_depth: ArrayLike, inverse_depth_variance: ArrayLike,
                           pattern: ArrayLike = PATTERN_SINGLE,
                           sigma_intensity: float = DEFAULT_SIGMA_INTENSITY) -> FloatArray:
    """The right image's brightness ``(a, b)`` relative to the left one: ``I_R ~ exp(a) I_L + b``.

    Fitted by weighted least squares over the points' pattern pixels at their stereo matches,
    weights ``W = (2 sigma_I^2 + (dr/dd)^2 V)^-1`` (a pixel on a strong horizontal gradient
    carries the depth's uncertainty), twice, the second time without the pixels whose residual
    exceeds 3 times the first fit's median absolute residual (occlusions, specularities). The two
    cameras of a rig have their own gain (KITTI: about 0.96 with an offset of 2-3 grey levels); a
    stereo term that ignores it pulls depths.
    The default pattern is the point's own pixel, where its stereo match was found (on the
    synthetic rig the 8-pixel pattern biases the log gain by 5e-3, the single pixel by 2e-3).
    Returns ``(0, 0)`` when fewer than 50 pixels are usable.
    """
    pat = np.asarray(pattern, dtype=float).reshape(-1, 2)
    I_L, ok_L = sample_host(left, pixels, pat)
    lin = stereo_residuals(camera, baseline, I_L, ok_L, pixels, inverse_depth, right, (0.0, 0.0), (0.0, 0.0), pat)
    ok = lin.valid
    if np.count_nonzero(ok) < 50:
        return np.zeros(2)
    x = I_L[ok]
    y = lin.residual[ok] + x  # I_R at the match
    sw = np.sqrt(variance_weight(lin.J_depth, inverse_depth_variance, sigma_intensity)[ok])
    keep = np.ones(x.shape[0], dtype=bool)
    gain, offset = 1.0, 0.0
    for _ in range(2):
        A = np.c_[x[keep], np.ones(np.count_nonzero(keep))] * sw[keep, None]
        gain, offset = np.linalg.lstsq(A, y[keep] * sw[keep], rcond=None)[0]
        res = np.abs(y - gain * x - offset)
        keep = res <= 3.0 * max(float(np.median(res)), 1e-6)
    if not (np.isfinite(gain) and gain > 0 and np.isfinite(offset)):
        return np.zeros(2)
    return np.array([np.log(gain), offset])


# ----------------------------------------------------------------------------------------------
# GTSAM solver


def build_graph(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                config: WindowConfig, marginal: MarginalPrior | None,
                targets: list[list[int]] | None = None
                ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, dict[int, HostPointsFactor]]:
    """The window's factor graph: one smart factor per host with targets, priors, motion prior,
    marginal prior.

    Returns ``(graph, values, host_factors)`` with ``host_factors[position] = factor``.
    """
    targets = visible_targets(camera, keyframes, config) if targets is None else targets
    graph = prior_factors(keyframes, config, with_gauge=marginal is None)
    for _, f in motion_factors(keyframes, config):
        graph.add(f)
    hosts: dict[int, HostPointsFactor] = {}
    for h, ts in enumerate(targets):
        if ts:
            f = host_factor(camera, baseline, keyframes, h, ts, config)
            hosts[h] = f
            graph.add(f)
    if marginal is not None:
        for f in marginal.nonlinear_factors():
            graph.add(f)
    return graph, window_values(keyframes), hosts


def solve_gtsam(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                config: WindowConfig, marginal: MarginalPrior | None = None,
                targets: list[list[int]] | None = None) -> WindowResult:
    """Optimise the window with ``gtsam.LevenbergMarquardtOptimizer``; updates ``keyframes`` in place."""
    t0 = time.perf_counter()
    targets = visible_targets(camera, keyframes, config) if targets is None else targets
    graph, values, hosts = build_graph(camera, baseline, keyframes, config, marginal, targets)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(config.max_iterations)
    params.setRelativeErrorTol(config.relative_tolerance)
    params.setAbsoluteErrorTol(0.0)
    params.setDiagonalDamping(True)  # Marquardt: lambda scales diag(H), as the hand-rolled solver
    params.setlambdaUpperBound(1e10)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    initial = opt.error()  # computed by the optimiser at construction: no extra pass
    result = opt.optimize()
    cost = opt.error()
    for h, f in hosts.items():
        keyframes[h].inverse_depth = f.commit(result).copy()
    for kf in keyframes:
        kf.pose = result.atPose3(pose_key(kf.index))
        kf.affine = np.asarray(result.atVector(affine_key(kf.index)), dtype=float).copy()
    n_res = sum(len(keyframes[h]) * len(ts) for h, ts in enumerate(targets))
    return WindowResult("gtsam", float(initial), float(cost), int(opt.iterations()), time.perf_counter() - t0, n_res)


# ----------------------------------------------------------------------------------------------
# hand-rolled solver: reduced camera system


class _HostTerms:
    """Frozen per-host data of the hand-rolled solver: host samples and the weights W.

    W is evaluated once, at the window's starting state, as :class:`HostPointsFactor` does at
    its first linearisation, so both solvers minimise the same fixed cost.
    """

    def __init__(self, camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                 h: int, targets: Sequence[int], config: WindowConfig) -> None:
        kh = keyframes[h]
        self.h, self.targets, self.camera, self.baseline, self.config = h, list(targets), camera, baseline, config
        self.host_I, self.host_valid = sample_host(kh.image, kh.pixels, config.pattern)
        self.bearings = pattern_bearings(camera, kh.pixels, config.pattern)  # fixed per host
        lins = self._lins(keyframes, kh.inverse_depth, [k.pose for k in keyframes], [k.affine for k in keyframes])
        self.W: list[FloatArray] = [variance_weight(lin.J_depth, kh.variance, config.sigma_intensity)
                                    for lin in lins[:-1]]
        self.W_stereo = None
        if lins[-1] is not None:
            self.W_stereo = config.lambda_stereo * variance_weight(lins[-1].J_depth, kh.variance,
                                                                   config.sigma_intensity)
        #: (E, lins) at the window's starting state: the initial cost and the first linearisation
        self.start = (self._cost_from(kh, kh.inverse_depth, lins), lins)

    def _lins(self, keyframes, d, poses, affines) -> list:
        """Linearisations (with Jacobians) into every target, then the stereo term (or None).

        LM evaluates the cost at a trial state and, when it accepts the step, linearises there:
        the Jacobians are computed in the cost pass (about a third of its time, the bilinear
        gathers being the rest) so that the accepted state is not evaluated twice.
        """
        kh = keyframes[self.h]
        out: list = [self._target(keyframes, t, d, poses, affines, jac=True) for t in self.targets]
        out.append(self._stereo(kh, d) if kh.right is not None else None)
        return out

    def _cost_from(self, kh: WindowKeyframe, d: FloatArray, lins: list) -> float:
        return float(self._point_costs_from(kh, d, lins).sum())

    def _point_costs_from(self, kh: WindowKeyframe, d: FloatArray, lins: list,
                          rows: NDArray[np.intp] | None = None) -> FloatArray:
        """Each point's cost: robust photometric and stereo losses and depth prior (``rows``: ``d``
        and ``lins`` hold only these points)."""
        sel = slice(None) if rows is None else rows
        c = np.zeros(d.shape[0] if rows is None else rows.size)
        for j, lin in enumerate(lins[:-1]):
            c += self._robust(self.W[j][sel], lin.residual)[1]
        if lins[-1] is not None:
            c += self._robust(self.W_stereo[sel], lins[-1].residual)[1]
        if kh.depth_prior:
            c += 0.5 * (d[sel] - kh.prior_inverse_depth[sel]) ** 2 / kh.variance[sel]
        return c

    def evaluate(self, keyframes, poses, affines, d) -> tuple[float, list]:
        """This host's cost at a state and the linearisations it was computed from."""
        lins = self._lins(keyframes, d, poses, affines)
        return self._cost_from(keyframes[self.h], d, lins), lins

    def evaluate_safeguarded(self, keyframes, poses, affines, d_new, d_old, c_old_lin
                             ) -> tuple[float, FloatArray, list]:
        """The cost at a trial state with the back-substituted inverse depths ``d_new``, except for
        points whose cost rose above their cost at the linearisation point (``c_old_lin``) and that
        cost less at their linearisation depth ``d_old``, which keep it (the safeguarded depth
        step of :class:`factors.smart.HostPointsFactor`): ``(cost, depths, linearisations)``."""
        kh = keyframes[self.h]
        lins = self._lins(keyframes, d_new, poses, affines)
        c = self._point_costs_from(kh, d_new, lins)
        d = d_new
        rows = np.flatnonzero(c > c_old_lin)
        if rows.size:
            lins_old = [self._target(keyframes, t, d_old, poses, affines, jac=True, rows=rows) for t in self.targets]
            lins_old.append(self._stereo(kh, d_old, rows) if kh.right is not None else None)
            c_old = self._point_costs_from(kh, d_old, lins_old, rows)
            d, c, lins = keep_cheaper_depths(d, c, lins, rows, d_old, c_old, lins_old)
        return float(c.sum()), d, lins

    def _target(self, keyframes, t, d, poses, affines, jac, rows=None):
        kh = keyframes[self.h]
        sel = slice(None) if rows is None else rows
        return photometric_residuals(self.camera, self.host_I[sel], self.host_valid[sel], kh.pixels[sel], d[sel],
                                     poses[self.h], poses[t], keyframes[t].image, affines[self.h], affines[t],
                                     self.config.pattern, jacobians=jac, host_jacobians=jac,
                                     bearings=self.bearings[sel])

    def _stereo(self, kh: WindowKeyframe, d: FloatArray, rows=None):
        sel = slice(None) if rows is None else rows
        return stereo_residuals(self.camera, self.baseline, self.host_I[sel], self.host_valid[sel], kh.pixels[sel],
                                d[sel], kh.right, (0.0, 0.0), kh.stereo_affine, self.config.pattern,
                                jacobians=False, bearings=self.bearings[sel])

    def _robust(self, W: FloatArray, r: FloatArray) -> tuple[FloatArray, FloatArray]:
        return point_robust_terms(W, r, self.config.huber_k)

    def cost(self, keyframes, poses, affines, d) -> float:
        return self.evaluate(keyframes, poses, affines, d)[0]

    def linearize(self, keyframes, poses, affines, d, H: FloatArray, g: FloatArray, lins: list | None = None):
        """Add this host's Gauss-Newton terms to the full ``H``, ``g`` (8 per keyframe); return
        ``(c (N,), H_pd (N, 8K), H_dd (N,), g_d (N,))`` with ``c`` each point's cost.
        ``lins``: :meth:`evaluate`'s at this state."""
        kh = keyframes[self.h]
        lins = self._lins(keyframes, d, poses, affines) if lins is None else lins
        n = d.shape[0]
        H_pd = np.zeros((n, H.shape[0]))
        H_dd = np.zeros(n)
        g_d = np.zeros(n)
        c = np.zeros(n)
        for j, t in enumerate(self.targets):
            lin = lins[j]
            w, loss = self._robust(self.W[j], lin.residual)
            c += loss
            # blocks [host pose, host affine, target pose, target affine]: 8 per keyframe
            H_t, g_t, H_pd_t, H_dd_t, g_d_t = gauss_newton_sums(lin, self.W[j] * w[:, None])
            cols = np.r_[8 * self.h:8 * self.h + 8, 8 * t:8 * t + 8]
            H[np.ix_(cols, cols)] += H_t
            g[cols] += g_t
            H_pd[:, cols] += H_pd_t
            H_dd += H_dd_t
            g_d += g_d_t
        if self.W_stereo is not None:
            st = lins[-1]
            w, loss = self._robust(self.W_stereo, st.residual)
            ww = self.W_stereo * w[:, None]
            H_dd += np.sum(ww * st.J_depth ** 2, axis=1)
            g_d += np.sum(ww * st.J_depth * st.residual, axis=1)
            c += loss
        if kh.depth_prior:
            H_dd += 1.0 / kh.variance
            g_d += (d - kh.prior_inverse_depth) / kh.variance
            c += 0.5 * (d - kh.prior_inverse_depth) ** 2 / kh.variance
        return c, H_pd, H_dd, g_d


def _prior_terms(keyframes, poses, affines, config, with_gauge, H=None, g=None, motion=None) -> float:
    """Affine priors, motion prior and gauge prior: cost, and (given H, g) their Gauss-Newton terms
    (``motion``: :func:`motion_factors` of these keyframes, if already built)."""
    E = 0.0
    for k, f in (motion_factors(keyframes, config) if motion is None else motion):
        e, J = f.whitened(poses[k], poses[k + 1], poses[k + 2])
        E += 0.5 * float(e @ e)
        if H is not None:
            for i in range(3):
                ri = slice(8 * (k + i), 8 * (k + i) + 6)
                g[ri] += J[i].T @ e
                for j in range(3):
                    H[ri, 8 * (k + j):8 * (k + j) + 6] += J[i].T @ J[j]
    s_aff = np.asarray(config.affine_sigma, dtype=float)
    for k, kf in enumerate(keyframes):
        e = (affines[k] - kf.affine_prior) / s_aff
        E += 0.5 * float(e @ e)
        if H is not None:
            idx = np.arange(8 * k + 6, 8 * k + 8)
            H[idx, idx] += 1.0 / s_aff ** 2
            g[idx] += e / s_aff
    if with_gauge:
        k0 = keyframes[0]
        s2 = config.gauge_sigma ** 2
        Jp = np.zeros((6, 6), order="F")
        e = np.asarray(k0.pose.localCoordinates(poses[0], None, Jp), dtype=float)
        ea = affines[0] - k0.affine
        E += 0.5 * float(e @ e + ea @ ea) / s2
        if H is not None:
            H[:6, :6] += Jp.T @ Jp / s2
            g[:6] += Jp.T @ e / s2
            H[6:8, 6:8] += np.eye(2) / s2
            g[6:8] += ea / s2
    return E


def _marginal_terms(marginal: MarginalPrior | None, keyframes, poses, affines, H=None, g=None) -> float:
    """The marginalisation prior's cost, and (given H, g) its terms (Jacobian of delta taken as I,
    as ``gtsam.LinearContainerFactor`` does)."""
    if marginal is None:
        return 0.0
    values = gtsam.Values()
    for k, kf in enumerate(keyframes):
        values.insert(pose_key(kf.index), poses[k])
        values.insert(affine_key(kf.index), affines[k])
    dl = marginal.delta(values)
    if H is not None:
        pos = {pose_key(kf.index): 8 * k for k, kf in enumerate(keyframes)}
        pos.update({affine_key(kf.index): 8 * k + 6 for k, kf in enumerate(keyframes)})
        idx = np.concatenate([np.arange(pos[key], pos[key] + dim) for key, dim in zip(marginal.keys, marginal.dims)])
        H[np.ix_(idx, idx)] += marginal.H
        g[idx] += marginal.H @ dl - marginal.eta
    return float(0.5 * dl @ marginal.H @ dl - marginal.eta @ dl + 0.5 * marginal.f)


def window_cost(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                config: WindowConfig, marginal: MarginalPrior | None = None,
                targets: list[list[int]] | None = None, terms: list[_HostTerms] | None = None) -> float:
    """The window cost E at the keyframes' current state, computed the hand-rolled way (W at this state)."""
    targets = visible_targets(camera, keyframes, config) if targets is None else targets
    if terms is None:
        terms = [_HostTerms(camera, baseline, keyframes, h, ts, config) for h, ts in enumerate(targets)]
    poses = [kf.pose for kf in keyframes]
    affines = [kf.affine for kf in keyframes]
    E = sum(t.cost(keyframes, poses, affines, keyframes[t.h].inverse_depth) for t in terms)
    E += _prior_terms(keyframes, poses, affines, config, marginal is None)
    return E + _marginal_terms(marginal, keyframes, poses, affines)


def solve_handrolled(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                     config: WindowConfig, marginal: MarginalPrior | None = None,
                     targets: list[list[int]] | None = None) -> WindowResult:
    """Levenberg-Marquardt on the reduced camera system; updates ``keyframes`` in place.

    Per iteration: every host's Gauss-Newton blocks over (poses, affines) ``x`` (8 per keyframe)
    and its inverse depths ``d`` (diagonal ``H_dd``), the Schur complement
    ``H_red = H_xx - sum_n H_xd H_xd^T / H_dd``, ``g_red = g_x - sum_n H_xd g_d / H_dd``, the
    damped step ``(H_red + lambda diag(H_red)) dx = -g_red`` and the back-substitution
    ``dd = -(g_d + H_xd^T dx) / H_dd``; the step is kept when the true cost decreases.
    """
    t0 = time.perf_counter()
    targets = visible_targets(camera, keyframes, config) if targets is None else targets
    terms = [_HostTerms(camera, baseline, keyframes, h, ts, config) for h, ts in enumerate(targets) if ts]
    K = len(keyframes)
    with_gauge = marginal is None
    poses = [kf.pose for kf in keyframes]
    affines = [kf.affine.copy() for kf in keyframes]
    depths = {t.h: keyframes[t.h].inverse_depth.copy() for t in terms}
    motion = motion_factors(keyframes, config)

    def cost(P, A, D_new, D_old, C_old) -> tuple[float, dict[int, FloatArray], dict[int, list]]:
        E, D, L = 0.0, {}, {}
        for t in terms:
            e, D[t.h], L[t.h] = t.evaluate_safeguarded(keyframes, P, A, D_new[t.h], D_old[t.h], C_old[t.h])
            E += e
        E += _prior_terms(keyframes, P, A, config, with_gauge, motion=motion)
        return E + _marginal_terms(marginal, keyframes, P, A), D, L

    E = sum(t.start[0] for t in terms) + _prior_terms(keyframes, poses, affines, config, with_gauge, motion=motion) \
        + _marginal_terms(marginal, keyframes, poses, affines)
    state_lins = {t.h: t.start[1] for t in terms}
    initial = E
    lam = 1e-5
    it = 0
    for it in range(1, config.max_iterations + 1):
        H = np.zeros((8 * K, 8 * K))
        g = np.zeros(8 * K)
        lins, point_costs = {}, {}
        for t in terms:
            point_costs[t.h], H_pd, H_dd, g_d = t.linearize(keyframes, poses, affines, depths[t.h], H, g,
                                                            state_lins[t.h])
            active = H_dd > 1e-12 * max(float(H_dd.max()), 1e-300)
            Hdd = np.where(active, H_dd, 1.0)
            L = H_pd[active] / Hdd[active, None]
            H -= L.T @ H_pd[active]
            g -= L.T @ g_d[active]
            lins[t.h] = (H_pd, Hdd, g_d, active)
        _prior_terms(keyframes, poses, affines, config, with_gauge, H, g, motion)
        _marginal_terms(marginal, keyframes, poses, affines, H, g)
        H = 0.5 * (H + H.T)
        diag = np.maximum(np.diag(H), 1e-12 * max(float(np.max(np.diag(H))), 1e-300))
        accepted = False
        for _ in range(10):
            dx = np.linalg.solve(H + lam * np.diag(diag), -g)
            P = [p.retract(dx[8 * k:8 * k + 6]) for k, p in enumerate(poses)]
            A = [a + dx[8 * k + 6:8 * k + 8] for k, a in enumerate(affines)]
            D = {}
            for h, (H_pd, Hdd, g_d, active) in lins.items():
                step = np.zeros_like(g_d)
                step[active] = -(g_d[active] + H_pd[active] @ dx) / Hdd[active]
                D[h] = np.maximum(depths[h] + step, 0.1 * depths[h])
            E_new, D, L_new = cost(P, A, D, depths, point_costs)
            if E_new < E:
                accepted = True
                break
            lam *= 10.0
        if not accepted:
            break
        decrease = E - E_new
        poses, affines, depths, E, state_lins = P, A, D, E_new, L_new
        lam = max(lam / 10.0, 1e-7)
        if decrease < config.relative_tolerance * max(E, 1e-300):
            break
    for k, kf in enumerate(keyframes):
        kf.pose = poses[k]
        kf.affine = np.asarray(affines[k], dtype=float).copy()
        if k in depths:
            kf.inverse_depth = depths[k].copy()
    n_res = sum(len(keyframes[h]) * len(ts) for h, ts in enumerate(targets))
    return WindowResult("handrolled", float(initial), float(E), it, time.perf_counter() - t0, n_res)


# ----------------------------------------------------------------------------------------------
# marginalisation and the window


def marginalize(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                config: WindowConfig, marginal: MarginalPrior | None, position: int = 0) -> MarginalPrior:
    """Marginalise ``keyframes[position]`` and its points; return the prior on the others.

    The factors touching it (its host factor into the keyframes that see its points, its affine
    prior, the motion priors it is part of, the gauge prior or the previous marginal prior) are
    linearised at the current state;
    its pose and affine are eliminated; what is left (a quadratic on the remaining keyframes) is
    the new prior, with the current state as its fixed linearisation point. Residuals of other
    hosts' points in the leaving keyframe are not part of it (they are dropped).
    """
    kf = keyframes[position]
    targets = visible_targets(camera, keyframes, config)[position]
    graph = gtsam.NonlinearFactorGraph()
    if targets:
        graph.add(host_factor(camera, baseline, keyframes, position, targets, config))
    aff_noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(config.affine_sigma, dtype=float))
    graph.add(gtsam.PriorFactorVector(affine_key(kf.index), np.asarray(kf.affine_prior, dtype=float), aff_noise))
    for k, f in motion_factors(keyframes, config):
        if k <= position <= k + 2:
            graph.add(f)
    if marginal is None:
        graph.add(gtsam.PriorFactorPose3(pose_key(kf.index), kf.pose, _gauge_noise(config, 6)))
        graph.add(gtsam.PriorFactorVector(affine_key(kf.index), kf.affine.copy(), _gauge_noise(config, 2)))
    else:
        for f in marginal.nonlinear_factors():
            graph.add(f)
    values = window_values(keyframes)
    linear = graph.linearize(values)
    leaving = [pose_key(kf.index), affine_key(kf.index)]
    _, remaining = linear.eliminatePartialMultifrontal(_ordering(leaving))
    present = set(remaining.keyVector())
    keys, dims = [], []
    for other in keyframes:
        for key, dim in ((pose_key(other.index), 6), (affine_key(other.index), 2)):
            if key in present:
                keys.append(key)
                dims.append(dim)
    aug = remaining.augmentedHessian(_ordering(keys))
    n = aug.shape[0] - 1
    H = 0.5 * (aug[:n, :n] + aug[:n, :n].T)
    return MarginalPrior(keys, dims, H, aug[:n, n].copy(), float(aug[n, n]), _subset(values, keys), remaining)


class SlidingWindowOptimizer:
    """A window of keyframes optimised jointly, with marginalisation of the keyframes that leave.

    Args:
        camera: left-camera intrinsics (all keyframes share them).
        baseline: stereo baseline (m), or None for RGB-D input.
        config: window settings.

    Example::

        window = SlidingWindowOptimizer(camera, baseline)
        window.add_keyframe(WindowKeyframe(...))   # marginalises the oldest when full
        result = window.optimize("gtsam")          # keyframes updated in place
    """

    def __init__(self, camera: PinholeCamera, baseline: float | None, config: WindowConfig | None = None) -> None:
        self.camera = camera
        self.baseline = baseline
        self.config = config or WindowConfig()
        self.keyframes: list[WindowKeyframe] = []
        self.marginal: MarginalPrior | None = None
        self.n_removed = 0  # keyframes that left the window (not kept: they hold images)
        self.results: list[WindowResult] = []
        # fixed-lag backend: the smoother, sequence numbers (timestamps) and host factors in it
        self._smoother: gtsam.IncrementalFixedLagSmoother | None = None
        self._stamp: dict[int, float] = {}
        self._next_stamp = 0
        self._host_slots: dict[int, tuple[int, HostPointsFactor]] = {}  # kf index -> (factor index, factor)
        self._motion_added: set[tuple[int, ...]] = set()  # keyframe triples whose motion prior is in the smoother

    def add_keyframe(self, keyframe: WindowKeyframe) -> None:
        """Append a keyframe; when the window is full, the oldest leaves first (marginalised)."""
        if any(k.index == keyframe.index for k in self.keyframes):
            raise InputError(f"keyframe {keyframe.index} is already in the window")
        while len(self.keyframes) >= self.config.size:
            self.remove_oldest()
        self.keyframes.append(keyframe)

    def remove_oldest(self) -> WindowKeyframe:
        """Remove the oldest keyframe: marginalised into the prior (or dropped, per the config).

        With the fixed-lag backend the smoother marginalises it at the next :meth:`optimize`.
        """
        if self.config.backend == "fixed_lag":
            kf = self.keyframes.pop(0)
            self.n_removed += 1
            return kf
        if self.config.marginalize:
            self.marginal = marginalize(self.camera, self.baseline, self.keyframes, self.config, self.marginal, 0)
        kf = self.keyframes.pop(0)
        self.n_removed += 1
        return kf

    def cost(self) -> float:
        """The window cost at the current state (W evaluated at this state)."""
        return window_cost(self.camera, self.baseline, self.keyframes, self.config, self.marginal)

    def optimize(self, solver: WindowSolverName = "gtsam") -> WindowResult | None:
        """Optimise the window (None when fewer than two keyframes); keyframes are updated in place.

        ``solver`` chooses the LM path's solver; the fixed-lag backend ignores it (GTSAM's smoother).
        """
        if len(self.keyframes) < 2:
            return None
        targets = visible_targets(self.camera, self.keyframes, self.config)
        if not any(targets):
            return None
        if self.config.backend == "fixed_lag":
            res = self._optimize_fixed_lag(targets)
        elif solver == "gtsam":
            res = solve_gtsam(self.camera, self.baseline, self.keyframes, self.config, self.marginal, targets)
        elif solver == "handrolled":
            res = solve_handrolled(self.camera, self.baseline, self.keyframes, self.config, self.marginal, targets)
        else:
            raise InputError(f"unknown window solver {solver!r}: use 'gtsam' or 'handrolled'")
        self.results.append(res)
        return res

    def _optimize_fixed_lag(self, targets: list[list[int]]) -> WindowResult:
        """One update of the fixed-lag smoother, then ``max_iterations - 1`` more (iSAM2 takes one
        Gauss-Newton step per update, relinearising every variable).

        Each call removes the host factors of the keyframes still in the window and adds them again
        with the current targets and depths (a host gains the new keyframe as a target); the host
        factor of a keyframe that has left stays and is marginalised with its pose and affine by
        the smoother (its depths frozen inside the marginal, as :func:`marginalize` does).
        Residuals of remaining hosts' points in the leaving keyframe are dropped (as in the LM path).
        """
        t0 = time.perf_counter()
        cfg = self.config
        if self._smoother is None:
            params = gtsam.ISAM2Params()
            params.setRelinearizeThreshold(0.0)
            params.relinearizeSkip = 1
            self._smoother = gtsam.IncrementalFixedLagSmoother(float(cfg.size) - 0.5, params)
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps: dict[int, float] = {}
        new = [kf for kf in self.keyframes if kf.index not in self._stamp]
        for kf in new:
            self._stamp[kf.index] = float(self._next_stamp)
            self._next_stamp += 1
            for key, val in ((pose_key(kf.index), kf.pose), (affine_key(kf.index), kf.affine)):
                values.insert(key, val)
                stamps[key] = self._stamp[kf.index]
        first = len(self._stamp) == len(new)
        priors = prior_factors(new, cfg, with_gauge=False)
        for k, f in motion_factors(self.keyframes, cfg):
            triple = tuple(kf.index for kf in self.keyframes[k:k + 3])
            if triple not in self._motion_added:  # each prior once; marginalised with its oldest keyframe
                self._motion_added.add(triple)
                priors.add(f)
        for i in range(priors.size()):
            graph.add(priors.at(i))
        if first:  # gauge prior on the oldest keyframe, once (later the marginal fixes the gauge)
            gauge = prior_factors(self.keyframes[:1], cfg, with_gauge=True)
            for i in range(1, gauge.size()):
                graph.add(gauge.at(i))
        in_window = {kf.index for kf in self.keyframes}
        remove = [slot for idx, (slot, _) in self._host_slots.items() if idx in in_window]
        # the window's hosts are removed and added again below; a leaving keyframe's host factor
        # stays in the smoother and is marginalised by this update: either way no slot survives
        self._host_slots = {}
        added: list[tuple[int, HostPointsFactor]] = []
        for h, ts in enumerate(targets):
            if ts:
                f = host_factor(self.camera, self.baseline, self.keyframes, h, ts, cfg)
                graph.add(f)
                added.append((self.keyframes[h].index, f))
        n_prior = graph.size() - len(added)
        self._smoother.update(graph, values, stamps, remove)
        ind = list(self._smoother.getISAM2Result().getNewFactorsIndices())
        for (idx, f), slot in zip(added, ind[n_prior:]):
            self._host_slots[idx] = (int(slot), f)
        for _ in range(cfg.max_iterations - 1):
            self._smoother.update()
        est = self._smoother.calculateEstimate()
        pos = {kf.index: h for h, kf in enumerate(self.keyframes)}
        for idx, (_, f) in self._host_slots.items():
            self.keyframes[pos[idx]].inverse_depth = f.commit(est).copy()
        for kf in self.keyframes:
            kf.pose = est.atPose3(pose_key(kf.index))
            kf.affine = np.asarray(est.atVector(affine_key(kf.index)), dtype=float).copy()
        n_res = sum(len(self.keyframes[h]) * len(ts) for h, ts in enumerate(targets))
        return WindowResult("fixed_lag", float("nan"), float("nan"), cfg.max_iterations,
                            time.perf_counter() - t0, n_res)

