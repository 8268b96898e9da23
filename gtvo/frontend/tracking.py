"""Frame-to-keyframe direct tracking, coarse to fine, solved two ways.

The keyframe's points (level-0 pixels, inverse depths ``d`` and variances ``V``) are fixed; the
unknowns are the frame's pose relative to the keyframe, ``T_keyframe_frame`` (GTSAM right
perturbation, [rotation, translation]), and optionally the frame's affine brightness
``(a, b)`` (the keyframe's is fixed). Both solvers minimise the same cost

    E = sum_n rho_huber(|e_n|),  e_n = sqrt(W_n) * r_n  (P pattern residuals of point n)

with ``r`` and ``W`` of :mod:`factors.photometric` (W and the Huber weight are evaluated at the
current state and frozen in the Jacobian, IRLS), over the pyramid from the coarsest level to 0:

* :func:`track_handrolled`: ``A = sum J^T w W J``, ``b = sum J^T w W r`` accumulated
  vectorised, ``(A + lambda diag(A)) dx = -b`` solved by Cholesky, inside the notes'
  Algorithm 3 schedule (lambda halves on success and drops to 0 below 0.2; on failure it goes
  to 0.2 from 0 or doubles; stop on a small step or the iteration limit).
* :func:`track_gtsam`: the same problem as one :class:`factors.gtsam_factors.PhotometricBatchFactor`
  per level solved by ``gtsam.LevenbergMarquardtOptimizer``.

Failure (too few valid points, a residual level that says the pose is wrong) is reported as
``TrackingResult.success = False`` with a reason, never a silent pose; ``raise_if_failed``
turns it into :class:`gtvo.errors.TrackingFailure`. Details: docs/tracking.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import gtsam
import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from factors.gtsam_factors import DEFAULT_HUBER_K, DEFAULT_SIGMA_INTENSITY, PhotometricBatchFactor
from factors.photometric import (DEFAULT_CLIP_RANGE, PATTERN_DSO8, GradientImage, pattern_bearings,
                                 photometric_residuals, sample_host)
from factors.weights import huber_loss, point_robust_terms, variance_weight
from gtvo.core.camera import PinholeCamera
from gtvo.core.keys import affine_key, pose_key
from gtvo.core.settings import check_settings, setting
from gtvo.errors import InputError, TrackingFailure
from gtvo.core.image import build_pyramid

FRAME_KEY = pose_key(1)
AFFINE_KEY = affine_key(1)


@dataclass(frozen=True)
class TrackingConfig:
    """Settings of the coarse-to-fine tracker (shared by both solvers).

    Attributes:
        levels: pyramid levels used (level 0 = full resolution).
        max_iterations: LM iterations per level.
        pattern: residual pattern (P, 2) in pixels of each level.
        sigma_intensity: sigma_I of the weight W.
        huber_k: Huber threshold on the whitened pattern norm of a point.
        clip_range: grey levels at which the sensor clipped (the images' ``GradientImage`` check;
            None: no check). In a VO run these four come from ``OdometryConfig.photometric``.
        estimate_affine: include the frame's affine brightness (a, b) in the state.
        step_tolerance: stop when the step is below this (pose in rad and m, log gain, offset b
            in units of 100 grey levels): 1e-5 rad moves a KITTI pixel by 0.007 px.
        max_rejections: consecutive rejected steps (lambda 0.2 .. 0.2 * 2^(n-1)) after which a
            level counts as converged (the model no longer predicts the cost at that scale).
        cost_tolerance: stop when an accepted step lowers the cost, or the Gauss-Newton model
            promises to lower it, by less than this fraction (GTSAM: relative error tolerance).
        min_valid_points: fewer points with a valid residual at level 0 is a failure.
        min_valid_fraction: a smaller fraction of the keyframe's points valid is a failure.
        max_rms: a whitened RMS residual per valid pixel above this at level 0 is a failure
            (the pose explains the images no better than noise of ``max_rms * sqrt(2) sigma_I``).
        max_outlier_fraction: more valid points than this fraction down-weighted by Huber at
            level 0 is a failure.
        max_abs_log_gain: a brightness gain ``|a| = |log(gain)|`` above this is a failure (a
            solver that explains an unrelated image by fading the keyframe out).
        max_rotation_sigma_deg: a rotation standard deviation (largest axis, from
            :attr:`TrackingResult.covariance`) above this is a failure: the images do not determine
            the rotation (few points, texture along one direction); the converged pose can then be
            tens of degrees off at a low residual.
        lost_point_norm: a point whose pattern leaves the frame (or goes behind it) costs
            ``rho(lost_point_norm)`` (spread over its pattern pixels), like a strong outlier;
            without it a solver lowers the cost by pushing points out of the image (seen on
            KITTI's coarsest level: a 2.5 deg pitch error that dropped 40 of 334 points).
        coarse_decay: level ``l`` uses every ``ceil(coarse_decay^l)``-th point (at least
            ``min_coarse_points``): a coarse image has fewer pixels to constrain the pose and the
            points crowd there; the finest level always uses all points.
        min_coarse_points: lower bound of the points used on a coarse level.
    """

    levels: int = setting(4, ">= 1")
    max_iterations: int = setting(12, ">= 1")
    pattern: NDArray[np.float64] = field(default_factory=lambda: PATTERN_DSO8.copy())
    sigma_intensity: float = DEFAULT_SIGMA_INTENSITY
    huber_k: float = DEFAULT_HUBER_K
    clip_range: tuple[float, float] | None = DEFAULT_CLIP_RANGE
    estimate_affine: bool = True
    step_tolerance: float = setting(1e-5, ">= 0")
    cost_tolerance: float = setting(1e-3, ">= 0")
    max_rejections: int = setting(2, ">= 0")
    min_valid_points: int = setting(30, ">= 0")
    min_valid_fraction: float = setting(0.1, "[0, 1]")
    max_rms: float = setting(2.0, "> 0")
    max_outlier_fraction: float = setting(0.6, "[0, 1]")
    max_abs_log_gain: float = setting(1.0, "> 0")
    max_rotation_sigma_deg: float = setting(1.0, "> 0")
    lost_point_norm: float = setting(6.0, ">= 0")
    coarse_decay: float = setting(2.0, ">= 1")
    min_coarse_points: int = setting(300, ">= 1")

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass
class TrackingResult:
    """Outcome of tracking one frame against a keyframe.

    Attributes:
        T_keyframe_frame: the frame's pose in the keyframe's camera frame
            (``T_world_frame = T_world_keyframe * T_keyframe_frame``).
        affine: the frame's affine brightness (a, b).
        cost: final robust cost E at level 0.
        initial_cost: E at level 0 at the initial guess.
        iterations: LM iterations over all levels.
        n_valid: points with at least one valid pattern residual at level 0.
        n_outliers: valid points whose Huber weight is below 1 at level 0.
        rms: whitened RMS residual per valid pixel at level 0 (``sqrt(2 E_valid / n)``, the robust
            cost of the valid pixels only).
        success: False when tracking failed; ``reason`` says why.
        covariance: (6, 6) covariance of ``T_keyframe_frame`` in GTSAM's tangent order [rotation
            (rad), translation (m)], right perturbation, the affine brightness marginalised: the
            inverse Gauss-Newton Hessian of E at level 0 at the solution (with the weights W that
            level's optimisation froze and Huber's at the solution; residuals whitened by
            ``sigma_intensity``, so it is as good as that noise model). All infinite where the
            Hessian is singular.
    """

    T_keyframe_frame: gtsam.Pose3
    affine: NDArray[np.float64]
    cost: float
    initial_cost: float
    iterations: int
    n_valid: int
    n_outliers: int
    rms: float
    success: bool
    reason: str = ""
    covariance: NDArray[np.float64] = field(default_factory=lambda: np.full((6, 6), np.inf))

    @property
    def rotation_sigma_deg(self) -> float:
        """Standard deviation of the rotation along its worst-determined axis (degrees)."""
        return _largest_sigma(self.covariance[:3, :3], np.degrees(1.0))

    @property
    def translation_sigma_m(self) -> float:
        """Standard deviation of the translation along its worst-determined axis (metres)."""
        return _largest_sigma(self.covariance[3:, 3:], 1.0)

    def raise_if_failed(self) -> "TrackingResult":
        """Return self, or raise :class:`TrackingFailure` with the reason."""
        if not self.success:
            raise TrackingFailure(self.reason)
        return self


def _largest_sigma(cov: NDArray[np.float64], scale: float) -> float:
    """``scale * sqrt(largest eigenvalue)`` of a covariance block; inf when it is not finite."""
    if not np.all(np.isfinite(cov)):
        return float("inf")
    return scale * float(np.sqrt(max(float(np.linalg.eigvalsh(0.5 * (cov + cov.T))[-1]), 0.0)))


def pose_covariance(A: NDArray[np.float64]) -> NDArray[np.float64]:
    """Covariance (6, 6) of the pose from the tracker's Gauss-Newton Hessian ``A`` (6x6, or 8x8 with
    the affine brightness last, which is marginalised): ``(A^-1)[:6, :6]``. A Hessian singular in
    some direction (relative to its largest eigenvalue, 1e-12) gives an all-infinite covariance."""
    A = 0.5 * (A + A.T)
    evals, evecs = np.linalg.eigh(A)
    if not np.all(np.isfinite(evals)) or evals[0] <= 1e-12 * max(float(evals[-1]), 1e-300):
        return np.full((6, 6), np.inf)
    return ((evecs / evals) @ evecs.T)[:6, :6]


class TrackingKeyframe:
    """A keyframe prepared for tracking: its pyramid and its points' host intensities per level.

    Args:
        camera: level-0 intrinsics.
        image: the keyframe's left image (H, W) in 8-bit units.
        pixels: (N, 2) level-0 pixels of its points.
        inverse_depth: (N,) inverse depths (> 0).
        inverse_depth_variance: (N,) variances V (>= 0).
        affine: the keyframe's affine brightness (a, b), held fixed.
        config: tracker settings (levels, pattern).
    """

    def __init__(self, camera: PinholeCamera, image: ArrayLike, pixels: ArrayLike, inverse_depth: ArrayLike,
                 inverse_depth_variance: ArrayLike, affine: ArrayLike = (0.0, 0.0),
                 config: TrackingConfig | None = None) -> None:
        self.config = config or TrackingConfig()
        px = np.asarray(pixels, dtype=float).reshape(-1, 2)
        n = px.shape[0]
        d = np.asarray(inverse_depth, dtype=float).reshape(-1)
        V = np.broadcast_to(np.asarray(inverse_depth_variance, dtype=float), (n,)).copy()
        if d.shape[0] != n:
            raise InputError(f"keyframe has {n} pixels but {d.shape[0]} inverse depths")
        if n == 0:
            raise InputError("keyframe has no points to track with")
        if not (np.all(np.isfinite(px)) and np.all(np.isfinite(d)) and np.all(np.isfinite(V))):
            raise InputError("keyframe points contain NaN or infinite pixels, inverse depths or variances")
        if np.any(V < 0):
            raise InputError("keyframe inverse-depth variances must be >= 0")
        img = np.asarray(image, dtype=np.float32)
        if img.shape[:2] != camera.shape:
            raise InputError(f"keyframe image is {img.shape[1]}x{img.shape[0]}, camera says "
                             f"{camera.width}x{camera.height}")
        self.camera = camera
        self.pixels, self.inverse_depth, self.variance = px, d, V
        self.affine = np.asarray(affine, dtype=float).reshape(2)
        pyr = build_pyramid(img, self.config.levels)
        self.levels = len(pyr)
        self.cameras = [camera.scaled(lv) for lv in range(self.levels)]
        pat = self.config.pattern
        self.level_index: list[NDArray[np.intp]] = []
        self.level_pixels: list[NDArray[np.float64]] = []
        self.level_bearings: list[NDArray[np.float64]] = []
        self.host_samples: list[tuple[NDArray, NDArray]] = []
        for lv in range(self.levels):
            step = max(1, int(np.ceil(self.config.coarse_decay ** lv)))
            step = min(step, max(1, n // max(1, self.config.min_coarse_points)))
            idx = np.arange(0, n, step)
            lp = (px[idx] + 0.5) / 2.0 ** lv - 0.5
            self.level_index.append(idx)
            self.level_pixels.append(lp)
            self.level_bearings.append(pattern_bearings(self.cameras[lv], lp, pat))
            self.host_samples.append(sample_host(GradientImage(pyr[lv], clip_range=self.config.clip_range), lp, pat))


def frame_pyramid(image: ArrayLike, levels: int,
                  clip_range: tuple[float, float] | None = DEFAULT_CLIP_RANGE) -> list[GradientImage]:
    """The frame's pyramid with gradients, one :class:`GradientImage` per level (``clip_range``:
    the keyframe's, ``TrackingConfig.clip_range``)."""
    return [GradientImage(p, clip_range=clip_range) for p in build_pyramid(np.asarray(image, dtype=np.float32), levels)]


def predict_constant_velocity(T_world_prev2: gtsam.Pose3, T_world_prev: gtsam.Pose3) -> gtsam.Pose3:
    """Motion-model guess of the next pose: repeat the last relative motion."""
    return T_world_prev.compose(T_world_prev2.between(T_world_prev))


@dataclass
class _Eval:
    cost: float
    A: NDArray[np.float64] | None
    b: NDArray[np.float64] | None
    n_valid: int
    n_outliers: int
    n_pixels: int
    W: NDArray[np.float64]
    data_cost: float  # without the lost-pixel cost


def level_weights(kf: TrackingKeyframe, level: int, target: GradientImage, T: gtsam.Pose3,
                  affine: NDArray) -> NDArray[np.float64]:
    """The variance weights W (N, P) at state (T, affine) on a level; frozen for that level's LM."""
    Ih, hv = kf.host_samples[level]
    idx = kf.level_index[level]
    lin = photometric_residuals(kf.cameras[level], Ih, hv, kf.level_pixels[level], kf.inverse_depth[idx], np.eye(4),
                                T.matrix(), target, kf.affine, affine, kf.config.pattern, jacobians=False,
                                bearings=kf.level_bearings[level])
    return variance_weight(lin.J_depth, kf.variance[idx], kf.config.sigma_intensity)


def _evaluate(kf: TrackingKeyframe, level: int, target: GradientImage, T: gtsam.Pose3, affine: NDArray,
              with_normal_equations: bool, W: NDArray | None = None) -> _Eval:
    cfg = kf.config
    Ih, hv = kf.host_samples[level]
    idx = kf.level_index[level]
    lin = photometric_residuals(kf.cameras[level], Ih, hv, kf.level_pixels[level], kf.inverse_depth[idx], np.eye(4),
                                T.matrix(), target, kf.affine, affine, cfg.pattern,
                                jacobians=with_normal_equations, host_jacobians=False,
                                bearings=kf.level_bearings[level])
    if W is None:
        W = variance_weight(lin.J_depth, kf.variance[idx], cfg.sigma_intensity)
    w, loss = point_robust_terms(W, lin.residual, cfg.huber_k)
    point_valid = lin.valid.any(axis=1)
    lost = int(np.count_nonzero(hv & (kf.inverse_depth[idx] > 0)[:, None] & ~lin.valid))
    data_cost = float(loss.sum())
    cost = data_cost + lost * _lost_pixel_loss(cfg)
    n_out = int(np.count_nonzero(point_valid & (w < 1.0)))
    A = b = None
    if with_normal_equations:
        ww = (W * w[:, None]).reshape(-1)
        if cfg.estimate_affine:
            J = np.concatenate([lin.J_target, lin.J_affine_target], axis=-1).reshape(-1, 8)
        else:
            J = lin.J_target.reshape(-1, 6)
        Jw = J * ww[:, None]
        A = J.T @ Jw
        b = Jw.T @ lin.residual.reshape(-1)
    return _Eval(cost, A, b, int(np.count_nonzero(point_valid)), n_out, int(np.count_nonzero(lin.valid)), W,
                 data_cost)


def _lost_pixel_loss(cfg: TrackingConfig) -> float:
    """Constant cost of a pattern pixel that the state pushes out of the frame (or behind it)."""
    return float(huber_loss(cfg.lost_point_norm, cfg.huber_k)) / cfg.pattern.shape[0]


def _apply(T: gtsam.Pose3, affine: NDArray, dx: NDArray) -> tuple[gtsam.Pose3, NDArray]:
    T2 = T.retract(dx[:6])
    a2 = affine + dx[6:8] if dx.shape[0] > 6 else affine
    return T2, a2


def _step_norm(dx: NDArray) -> float:
    """Size of a step: pose (rad, m) and log gain as they are, the offset b in units of 100 grey levels."""
    scaled = dx.copy()
    if scaled.shape[0] > 7:
        scaled[7] *= 0.01
    return float(np.linalg.norm(scaled))


def _solve(A: NDArray, b: NDArray, lam: float) -> NDArray:
    Ad = A + lam * np.diag(np.diag(A)) + 1e-12 * np.trace(A) / A.shape[0] * np.eye(A.shape[0])
    try:
        return -scipy.linalg.cho_solve(scipy.linalg.cho_factor(Ad), b)
    except np.linalg.LinAlgError:
        return -np.linalg.lstsq(Ad, b, rcond=None)[0]


def _lm_level(kf: TrackingKeyframe, level: int, target: GradientImage, T: gtsam.Pose3,
              affine: NDArray) -> tuple[gtsam.Pose3, NDArray, int, NDArray]:
    """The notes' Algorithm 3 on one level; returns the new state, the iterations and the frozen W."""
    cfg = kf.config
    cur = _evaluate(kf, level, target, T, affine, True)
    W = cur.W
    if cur.n_pixels < 6:
        return T, affine, 0, W
    lam = 0.0
    it = 0
    done = False
    while it < cfg.max_iterations and not done:
        it += 1
        rejected = 0
        while True:
            dx = _solve(cur.A, cur.b, lam)
            predicted = -float(cur.b @ dx + 0.5 * dx @ cur.A @ dx)  # decrease the GN model promises
            if predicted < cfg.cost_tolerance * cur.cost:
                done = True  # converged: no step can gain more than the tolerance
                break
            T_new, a_new = _apply(T, affine, dx)
            new = _evaluate(kf, level, target, T_new, a_new, True, W)
            small = _step_norm(dx) < cfg.step_tolerance
            if new.cost < cur.cost and new.n_pixels >= 6:
                converged = cur.cost - new.cost < cfg.cost_tolerance * cur.cost
                T, affine, cur = T_new, a_new, new
                lam = 0.0 if lam <= 0.2 else 0.5 * lam
                done = small or converged
                break
            rejected += 1
            if small or rejected > cfg.max_rejections:
                done = True
                break
            lam = 0.2 if lam == 0.0 else 2.0 * lam
    return T, affine, it, W


def _finish(kf: TrackingKeyframe, target0: GradientImage, T: gtsam.Pose3, affine: NDArray, initial_cost: float,
            iterations: int, W0: NDArray | None) -> TrackingResult:
    cfg = kf.config
    ev = _evaluate(kf, 0, target0, T, affine, True, W0)
    rms = float(np.sqrt(2.0 * ev.data_cost / ev.n_pixels)) if ev.n_pixels else float("inf")
    assert ev.A is not None
    cov = pose_covariance(ev.A) if ev.n_pixels else np.full((6, 6), np.inf)
    sigma_rot = _largest_sigma(cov[:3, :3], np.degrees(1.0))
    n = kf.pixels.shape[0]
    reason = ""
    if not (np.all(np.isfinite(T.matrix())) and np.all(np.isfinite(affine)) and np.isfinite(ev.cost)):
        reason = "tracking diverged: non-finite pose or cost"
    elif ev.n_valid < cfg.min_valid_points:
        reason = f"too few valid points: {ev.n_valid} < {cfg.min_valid_points}"
    elif ev.n_valid < cfg.min_valid_fraction * n:
        reason = f"too few valid points: {ev.n_valid} of {n} (< {cfg.min_valid_fraction:.0%})"
    elif rms > cfg.max_rms:
        reason = f"residual too large after tracking: whitened RMS {rms:.3g} > {cfg.max_rms}"
    elif ev.n_outliers > cfg.max_outlier_fraction * ev.n_valid:
        reason = (f"residual too large after tracking: {ev.n_outliers} of {ev.n_valid} points are outliers "
                  f"(> {cfg.max_outlier_fraction:.0%})")
    elif abs(float(affine[0]) - float(kf.affine[0])) > cfg.max_abs_log_gain:
        reason = (f"implausible brightness change: log gain {float(affine[0]) - float(kf.affine[0]):.3g} "
                  f"(limit {cfg.max_abs_log_gain})")
    elif not sigma_rot <= cfg.max_rotation_sigma_deg:
        reason = (f"pose poorly constrained: rotation sigma {sigma_rot:.3g} deg > {cfg.max_rotation_sigma_deg} "
                  "(the images do not determine the rotation)")
    return TrackingResult(T, np.asarray(affine, dtype=float).copy(), ev.cost, initial_cost, iterations, ev.n_valid,
                          ev.n_outliers, rms, reason == "", reason, cov)


def _prepare(kf: TrackingKeyframe, frame: ArrayLike | list[GradientImage],
             T_keyframe_frame_init: gtsam.Pose3 | None, affine_init: ArrayLike | None):
    pyr = frame if isinstance(frame, list) else frame_pyramid(frame, kf.levels, kf.config.clip_range)
    if len(pyr) < kf.levels:
        raise InputError(f"frame pyramid has {len(pyr)} levels, keyframe {kf.levels}")
    if (pyr[0].height, pyr[0].width) != kf.camera.shape:
        raise InputError(f"frame image is {pyr[0].width}x{pyr[0].height}, camera says "
                         f"{kf.camera.width}x{kf.camera.height}")
    T = gtsam.Pose3() if T_keyframe_frame_init is None else T_keyframe_frame_init
    affine = np.zeros(2) if affine_init is None else np.asarray(affine_init, dtype=float).reshape(2).copy()
    if not kf.config.estimate_affine and affine_init is None:
        affine = kf.affine.copy()
    return pyr, T, affine


def track_handrolled(keyframe: TrackingKeyframe, frame: ArrayLike | list[GradientImage],
                     T_keyframe_frame_init: gtsam.Pose3 | None = None,
                     affine_init: ArrayLike | None = None) -> TrackingResult:
    """Track a frame against a keyframe with the hand-rolled vectorised LM (Algorithm 3).

    Args:
        keyframe: the prepared keyframe.
        frame: the frame's left image (H, W) or its :func:`frame_pyramid`.
        T_keyframe_frame_init: initial guess (e.g. from :func:`predict_constant_velocity`);
            identity when None.
        affine_init: initial (a, b) of the frame (zeros when None).
    """
    pyr, T, affine = _prepare(keyframe, frame, T_keyframe_frame_init, affine_init)
    initial_cost = _evaluate(keyframe, 0, pyr[0], T, affine, False).cost
    total = 0
    W = None
    for level in range(keyframe.levels - 1, -1, -1):
        T, affine, it, W = _lm_level(keyframe, level, pyr[level], T, affine)
        total += it
    return _finish(keyframe, pyr[0], T, affine, initial_cost, total, W)


def track_gtsam(keyframe: TrackingKeyframe, frame: ArrayLike | list[GradientImage],
                T_keyframe_frame_init: gtsam.Pose3 | None = None,
                affine_init: ArrayLike | None = None) -> TrackingResult:
    """Track a frame against a keyframe with ``gtsam.LevenbergMarquardtOptimizer``.

    Same problem and arguments as :func:`track_handrolled`: per level one
    :class:`factors.gtsam_factors.PhotometricBatchFactor` (keyframe pose fixed at identity,
    depths fixed) over ``x1`` (the frame's ``T_keyframe_frame``) and, with ``estimate_affine``,
    ``a1`` (its affine brightness).
    """
    cfg = keyframe.config
    pyr, T, affine = _prepare(keyframe, frame, T_keyframe_frame_init, affine_init)
    initial_cost = _evaluate(keyframe, 0, pyr[0], T, affine, False).cost
    total = 0
    W = None
    for level in range(keyframe.levels - 1, -1, -1):
        W = level_weights(keyframe, level, pyr[level], T, affine)
        idx = keyframe.level_index[level]
        factor = PhotometricBatchFactor(
            FRAME_KEY, keyframe.cameras[level], keyframe.level_pixels[level], keyframe.inverse_depth[idx],
            None, pyr[level], keyframe.variance[idx], affine_host=keyframe.affine,
            affine_target_key=AFFINE_KEY if cfg.estimate_affine else None, affine_target=affine,
            sigma_intensity=cfg.sigma_intensity, huber_k=cfg.huber_k, pattern=cfg.pattern,
            host_intensity=keyframe.host_samples[level],
            weights=W, bearings=keyframe.level_bearings[level], lost_pixel_loss=_lost_pixel_loss(cfg))
        graph = gtsam.NonlinearFactorGraph()
        graph.add(factor)
        values = gtsam.Values()
        values.insert(FRAME_KEY, T)
        if cfg.estimate_affine:
            values.insert(AFFINE_KEY, affine)
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(cfg.max_iterations)
        params.setRelativeErrorTol(cfg.cost_tolerance)
        params.setAbsoluteErrorTol(0.0)
        opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        try:
            res = opt.optimize()
        except RuntimeError as exc:  # indeterminant system: no valid residuals at this level
            if "Indeterminant" not in str(exc) and "indeterminant" not in str(exc):
                raise
            continue
        total += int(opt.iterations())
        T = res.atPose3(FRAME_KEY)
        if cfg.estimate_affine:
            affine = np.asarray(res.atVector(AFFINE_KEY), dtype=float)
    return _finish(keyframe, pyr[0], T, affine, initial_cost, total, W)


def track_with_guesses(keyframe: TrackingKeyframe, frame: ArrayLike | list[GradientImage],
                       guesses: Sequence[gtsam.Pose3], affine_init: ArrayLike | None = None,
                       solver: Callable[..., TrackingResult] = track_handrolled,
                       accept_rms: float | None = None) -> TrackingResult:
    """Track from several initial guesses; return a good or the best successful result.

    Coarse-to-fine has a basin of a few pixels on the coarsest level, and a motion-model guess
    that carries the last frame's rotation error can end in a wrong local minimum that still
    passes the failure checks (seen on KITTI: 1.6 deg pitch error at twice the cost of the true
    minimum, whitened RMS 1.83 instead of 1.27). Typical guesses, best first: the
    constant-velocity prediction, the previous frame's pose (no motion), the keyframe's pose.

    Args:
        keyframe, frame, affine_init: as in :func:`track_handrolled`.
        guesses: initial ``T_keyframe_frame`` values, best first (at least one).
        solver: :func:`track_handrolled` or :func:`track_gtsam`.
        accept_rms: a successful result with ``rms <= accept_rms`` is returned at once (e.g.
            1.3 x the previous frame's RMS). Otherwise every guess is tried and the successful
            result with the lowest cost is returned. None: the first success is returned.

    When all fail, the failed result with the lowest RMS is returned (``success`` False, its
    reason prefixed by the number of guesses tried).
    """
    if len(guesses) == 0:
        raise InputError("track_with_guesses needs at least one initial guess")
    pyr = frame if isinstance(frame, list) else frame_pyramid(frame, keyframe.levels, keyframe.config.clip_range)
    best_ok: TrackingResult | None = None
    best_failed: TrackingResult | None = None
    for guess in guesses:
        r = solver(keyframe, pyr, guess, affine_init)
        if r.success:
            if accept_rms is None or r.rms <= accept_rms:
                return r
            if best_ok is None or r.cost < best_ok.cost:
                best_ok = r
        elif best_failed is None or r.rms < best_failed.rms:
            best_failed = r
    if best_ok is not None:
        return best_ok
    assert best_failed is not None
    best_failed.reason = f"all {len(guesses)} initial guesses failed; best: {best_failed.reason}"
    return best_failed
