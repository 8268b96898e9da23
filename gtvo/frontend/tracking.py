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

from dataclasses import dataclass
from typing import Callable, Sequence

import gtsam
import numpy as np
import scipy.linalg
import scipy.linalg.lapack
from numpy.typing import ArrayLike, NDArray

from factors.gtsam_factors import PhotometricBatchFactor
from factors.host_points import target_normal_equations
from factors.photometric import (GradientImage, PhotometricLinearization, compiled_residuals,
                                 photometric_residuals)
from factors.weights import huber_loss, point_robust_terms, variance_weight
from gtvo.core.camera import MIN_DEPTH
from gtvo.core.keys import affine_key, pose_key
from gtvo.core.lie import invert_poses
from gtvo.errors import InputError
from gtvo.frontend._compiled import damped_system, tracker_terms

from gtvo.frontend.tracking_types import (PhotometricConfig, PointResiduals, TrackingConfig, TrackingKeyframe,
                                          TrackingResult, frame_pyramid, largest_sigma, pose_covariance)

__all__ = ["AFFINE_KEY", "FRAME_KEY", "PhotometricConfig", "TrackingConfig", "TrackingKeyframe", "TrackingResult", "frame_pyramid",
           "level_weights", "point_residuals", "pose_covariance", "predict_constant_velocity", "track_gtsam", "track_handrolled",
           "track_with_guesses"]

FRAME_KEY = pose_key(1)
AFFINE_KEY = affine_key(1)


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
    residual: NDArray[np.float64]  # (N, P) the residuals it was computed from
    valid: NDArray[np.bool_]  # (N, P) their validity (the unrelated-image RMS reads it)


_IDENTITY = np.eye(4)  # the keyframe's own pose: the tracker works in its frame


def _residuals(kf: TrackingKeyframe, level: int, target: GradientImage, T: gtsam.Pose3, affine: NDArray,
               jacobians: bool) -> PhotometricLinearization:
    """The keyframe's points of a level in ``target`` at ``(T, affine)`` (target Jacobians only):
    the compiled loops without ``photometric_residuals``' per-call checks and layout (the
    keyframe's arrays are laid out once) for a :class:`GradientImage`, the same values."""
    Ih, hv = kf.host_samples[level]
    d = kf.level_inverse_depth[level]
    if isinstance(target, GradientImage):
        a_h, b_h = (float(x) for x in kf.affine)
        a_t, b_t = (float(x) for x in np.asarray(affine, dtype=float).reshape(2))
        return compiled_residuals(kf.cameras[level], Ih, hv, kf.level_bearings[level], d,
                                  _IDENTITY, T.matrix(), target, a_t - a_h, b_h, b_t, jacobians, False)
    return photometric_residuals(kf.cameras[level], Ih, hv, kf.level_pixels[level], d, _IDENTITY, T.matrix(), target,
                                 kf.affine, affine, kf.pattern, jacobians=jacobians, host_jacobians=False,
                                 bearings=kf.level_bearings[level])


def level_weights(kf: TrackingKeyframe, level: int, target: GradientImage, T: gtsam.Pose3,
                  affine: NDArray) -> NDArray[np.float64]:
    """The variance weights W (N, P) at state (T, affine) on a level; frozen for that level's LM."""
    lin = _residuals(kf, level, target, T, affine, False)
    return variance_weight(lin.J_depth, kf.level_variance[level], kf.photometric.sigma_intensity)


def _evaluate(kf: TrackingKeyframe, level: int, target: GradientImage, T: gtsam.Pose3, affine: NDArray,
              with_normal_equations: bool, W: NDArray | None = None) -> _Eval:
    cfg, model = kf.config, kf.photometric
    if isinstance(target, GradientImage):
        return _evaluate_compiled(kf, level, target, T, affine, with_normal_equations, W)
    lin = _residuals(kf, level, target, T, affine, with_normal_equations)
    if W is None:
        W = variance_weight(lin.J_depth, kf.level_variance[level], model.sigma_intensity)
    w, loss = point_robust_terms(W, lin.residual, model.huber_k)
    point_valid = lin.valid.any(axis=1)
    lost = int(np.count_nonzero(kf.level_countable[level] & ~lin.valid))
    data_cost = float(loss.sum())
    cost = data_cost + lost * _lost_pixel_loss(kf) if lost else data_cost  # (+ 0.0: the same cost)
    n_out = int(np.count_nonzero(point_valid & (w < 1.0)))
    A = b = None
    if with_normal_equations:
        A, b = target_normal_equations(lin, W * w[:, None], cfg.estimate_affine)
    return _Eval(cost, A, b, int(np.count_nonzero(point_valid)), n_out, int(np.count_nonzero(lin.valid)), W,
                 data_cost, lin.residual, lin.valid)


def _evaluate_compiled(kf: TrackingKeyframe, level: int, target: GradientImage, T: gtsam.Pose3, affine: NDArray,
                       with_normal_equations: bool, W: NDArray | None) -> _Eval:
    """:func:`_evaluate` for a :class:`GradientImage` target in one compiled call
    (:func:`gtvo.frontend._compiled.tracker_terms`): the residuals of :func:`_residuals`, the
    weights, Huber terms, counts and normal equations of the numpy steps, the same numbers, without
    their dozen passes over the residuals and the arrays between them."""
    model = kf.photometric
    Ih, hv = kf.host_samples[level]
    cam = kf.cameras[level]
    a_h, b_h = kf.affine.tolist()  # Python floats, as float() of each
    a_t, b_t = np.asarray(affine, dtype=float).reshape(2).tolist()
    T_target_host = invert_poses(T.matrix()) @ _IDENTITY  # factors.photometric's T_world_target^-1 T_world_host
    given = W is not None
    k = model.huber_k
    r, valid, W_out, loss, ints, A, b = tracker_terms(
        *target._sampler_args(), float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy), float(MIN_DEPTH),
        np.ascontiguousarray(T_target_host[:3, :3]), np.ascontiguousarray(T_target_host[:3, 3]),
        kf.level_bearings[level], kf.level_inverse_depth[level], Ih, hv, float(np.exp(a_t - a_h)), b_h, b_t,
        bool(with_normal_equations), np.ascontiguousarray(W, dtype=float) if given else _NO_WEIGHTS, given,
        kf.level_variance[level], 2.0 * model.sigma_intensity ** 2, 0.0 if k is None else float(k), k is not None,
        kf.level_countable[level], bool(kf.config.estimate_affine))
    n_valid, n_out, n_pixels, lost = (int(c) for c in ints)
    data_cost = float(loss.sum())
    cost = data_cost + lost * _lost_pixel_loss(kf) if lost else data_cost  # (+ 0.0: the same cost)
    if not with_normal_equations:
        A = b = None
    return _Eval(cost, A, b, n_valid, n_out, n_pixels, W if given else W_out, data_cost, r, valid)


_NO_WEIGHTS = np.zeros((0, 0))  # tracker_terms' "compute the weights"


def _lost_pixel_loss(kf: TrackingKeyframe) -> float:
    """Constant cost of a pattern pixel that the state pushes out of the frame (or behind it);
    computed once per keyframe and settings (the tracker asks at every cost evaluation)."""
    norm, k, p = kf.config.lost_point_norm, kf.photometric.huber_k, kf.pattern.shape[0]
    cached = kf.__dict__.get("_lost_pixel_loss")
    if cached is not None and cached[0] == (norm, k, p):
        return cached[1]
    loss = 0.5 * norm * norm if k is None else float(huber_loss(norm, k))  # no robust kernel: the square's
    kf._lost_pixel_loss = ((norm, k, p), loss / p)
    return loss / p


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
    """The damped step ``-(A + lam diag(A) + eps I)^-1 b`` by Cholesky, least squares when that
    fails. LAPACK's ``potrf`` / ``potrs`` called directly: what ``scipy.linalg.cho_factor`` and
    ``cho_solve`` call (the same numbers) without their per-call checks and wrappers, which cost
    7x the 8x8 factorisation itself; a non-finite system raises ``ValueError`` as they do. The damped
    matrix ``A + lam diag(A) + eps I`` (eps: 1e-12 of the mean diagonal) is made in one compiled call."""
    Ad, finite = damped_system(A, b, float(lam), 1e-12 * np.trace(A) / A.shape[0])  # the numpy expression's numbers
    if not finite:
        raise ValueError("tracking: the normal equations contain infs or NaNs")
    c, info = _POTRF(Ad, lower=0, overwrite_a=0, clean=0)
    if info == 0:
        x, info = _POTRS(c, b, lower=0, overwrite_b=0)
        if info == 0:
            return -x
    return -np.linalg.lstsq(Ad, b, rcond=None)[0]


_POTRF, _POTRS = scipy.linalg.lapack.get_lapack_funcs(("potrf", "potrs"), (np.zeros((2, 2)),))


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
    sigma_rot = largest_sigma(cov[:3, :3], np.degrees(1.0))
    n = kf.pixels.shape[0]
    unrelated = _unrelated_rms(kf, ev)
    relative = rms / unrelated if unrelated > 0 else float("inf")
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
    elif not relative <= cfg.max_relative_rms:
        reason = (f"the images do not determine the pose: residual {relative:.2f} of an unrelated image's "
                  f"(> {cfg.max_relative_rms}; too dark or too flat)")
    return TrackingResult(T, np.asarray(affine, dtype=float).copy(), ev.cost, initial_cost, iterations, ev.n_valid,
                          ev.n_outliers, rms, reason == "", reason, cov, relative)


def _unrelated_rms(kf: TrackingKeyframe, ev: _Eval) -> float:
    """The whitened RMS residual on level 0 of an image unrelated to the keyframe but of its contrast:
    ``sqrt(2 Var(I_kf) mean(W))`` over the valid pattern pixels (two independent draws of the
    keyframe's intensities differ by ``2 Var`` in the mean square); NaN without valid pixels."""
    valid = ev.valid
    if not valid.any():
        return float("nan")
    host = kf.host_samples[0][0]
    return float(np.sqrt(2.0 * np.var(host[valid]) * np.mean(ev.W[valid])))


def point_residuals(keyframe: TrackingKeyframe, target: GradientImage, T_keyframe_frame: gtsam.Pose3,
                    affine: ArrayLike) -> PointResiduals:
    """The tracker's own photometric residuals of ``keyframe``'s points in ``target`` (the frame's
    level 0) at ``(T_keyframe_frame, affine)``, e.g. a :class:`TrackingResult`'s solution: per point
    with a valid pattern pixel, where the frame sees it and its RMS residual. Computed on demand
    (for viewers), not by the tracker itself: its hot loop never pays for it."""
    lin = _residuals(keyframe, 0, target, T_keyframe_frame, np.asarray(affine, dtype=float), False)
    return _point_residuals(lin, keyframe.level_index[0], keyframe.pattern)


def _point_residuals(lin: PhotometricLinearization, index: NDArray[np.intp], pattern: ArrayLike) -> PointResiduals:
    """Per point with a valid pattern pixel: where the frame sees it (its valid pattern pixels'
    warps less their pattern offsets, averaged) and its RMS residual over them."""
    n = lin.valid.sum(axis=1)
    seen = n > 0
    valid = lin.valid[seen]
    count = n[seen, None]
    centred = lin.uv_target[seen] - np.asarray(pattern, dtype=float)[None, :, :]
    pixels = np.where(valid[:, :, None], centred, 0.0).sum(axis=1) / count
    residual = np.sqrt(np.where(valid, np.square(lin.residual[seen]), 0.0).sum(axis=1) / count[:, 0])
    return PointResiduals(np.asarray(index)[seen], pixels, residual)


def _prepare(kf: TrackingKeyframe, frame: ArrayLike | list[GradientImage],
             T_keyframe_frame_init: gtsam.Pose3 | None, affine_init: ArrayLike | None):
    pyr = frame if isinstance(frame, list) else frame_pyramid(frame, kf.levels, kf.photometric.clip_range)
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
            sigma_intensity=keyframe.photometric.sigma_intensity, huber_k=keyframe.photometric.huber_k,
            pattern=keyframe.pattern,
            host_intensity=keyframe.host_samples[level],
            weights=W, bearings=keyframe.level_bearings[level], lost_pixel_loss=_lost_pixel_loss(keyframe))
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
    pyr = frame if isinstance(frame, list) else frame_pyramid(frame, keyframe.levels, keyframe.photometric.clip_range)
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
