"""The photometric GTSAM factors, built on the vectorised kernels of :mod:`factors.photometric`.

Every factor here is a ``gtsam.CustomFactor`` subclass (through :class:`PythonFactor`, which
lets GTSAM free it) with analytic Jacobians and works in a
plain ``gtsam.NonlinearFactorGraph`` with ``gtsam.LevenbergMarquardtOptimizer``. Keys:
:mod:`gtvo.core.keys` (poses ``pose_key(i)``, Pose3 ``T_world_cam``; inverse depths
``inverse_depth_key(j)``, double; left and right affine brightness ``affine_key(i)``,
``right_affine_key(i)``, Vector2 ``(a, b)``). The smoothness priors are in :mod:`factors.smoothness`.

Weights. The photometric and stereo factors whiten their residuals by the notes' variance
weight ``sqrt(W)``, ``W = (2 sigma_I^2 + (dr/dd)^2 V)^-1`` (:mod:`factors.weights`), evaluated at the current values
and treated as constant in the Jacobian (Gauss-Newton/IRLS, as in the notes' eq. for J^T W J);
the robust kernel is ``gtsam.noiseModel.Robust`` (Huber by default) on the whitened pattern
vector of one point. Python factors are slow inside GTSAM's optimisers (each call copies the
whole Values, docs/factors.md): for many points use :class:`PhotometricBatchFactor` (tracking,
fixed depths) or :class:`factors.smart.HostPointsFactor` (depths Schur-eliminated).
"""

from __future__ import annotations

from typing import Sequence

import gtsam
import numpy as np
from numpy.typing import ArrayLike

from factors.photometric import (PATTERN_DSO8, GradientSampler, pattern_bearings, photometric_residuals, sample_host,
                                 stereo_residuals)
from factors.weights import huber_loss, huber_weight, variance_weight
from gtvo.core.camera import PinholeCamera
from gtvo.errors import InputError

#: Default intensity noise sigma_I (8-bit units) of one image (KITTI: RMS whitened residual ~1.1 with it).
DEFAULT_SIGMA_INTENSITY = 8.0
#: Default Huber threshold on the whitened pattern norm of one point (sqrt(8) ~ 2.8 is typical).
DEFAULT_HUBER_K = 3.0


def robust_unit_noise(dim: int, huber_k: float | None) -> gtsam.noiseModel.Base:
    """Unit noise of ``dim`` wrapped in a Huber kernel (``huber_k`` None: plain unit noise)."""
    unit = gtsam.noiseModel.Unit.Create(dim)
    if huber_k is None:
        return unit
    if not huber_k > 0:
        raise InputError(f"huber_k must be positive, got {huber_k!r}")
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(float(huber_k)), unit)


class PythonFactor(gtsam.CustomFactor):
    """Base of the factors written in Python: a ``CustomFactor`` that can be freed.

    GTSAM keeps the error function a ``CustomFactor`` is built with for as long as the C++
    factor lives. Given a bound method of the factor itself (``self._evaluate``), the C++ object
    refers to the Python object and the Python object to the C++ object, a cycle that Python's
    garbage collector cannot see through C++: every such factor, with the images it holds, stays
    in memory until the process ends (measured: 11-20 MB per KITTI keyframe, 1 GB per 51 frames).

    Here the error function is bound to a plain Python *twin* of the factor instead: an
    instance of a class with the same Python methods (those of every class between the factor's
    class and this one) that shares the factor's attribute dictionary. The twin refers to the
    attributes, not to the factor, so the C++ object keeps only what the error needs alive; once
    neither Python nor a graph refers to the factor, everything is freed. A factor added to a
    graph and dropped by Python still evaluates (the twin lives in the graph's C++ factor).

    Subclasses set their attributes, then call ``super().__init__(noise_model, keys)``; their
    ``_evaluate(this, values, H)`` (and whatever it calls) must use only Python attributes and
    methods of the factor, not the C++ ``CustomFactor`` API (the twin has none).
    """

    def __init__(self, noise_model: gtsam.noiseModel.Base, keys: Sequence[int]) -> None:
        twin = _twin_class(type(self))()
        twin.__dict__ = self.__dict__
        super().__init__(noise_model, list(keys), twin._evaluate)

    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        raise NotImplementedError


_TWIN_CLASSES: dict[type, type] = {}


def _twin_class(cls: type) -> type:
    """A plain class with the Python methods of ``cls`` up to :class:`PythonFactor` (cached)."""
    twin = _TWIN_CLASSES.get(cls)
    if twin is None:
        namespace: dict[str, object] = {}
        for klass in reversed(cls.__mro__):
            if issubclass(klass, PythonFactor):
                namespace.update({k: v for k, v in vars(klass).items()
                                  if not (k.startswith("__") and k.endswith("__"))})
        twin = type(f"{cls.__name__}Evaluator", (), namespace)
        _TWIN_CLASSES[cls] = twin
    return twin


def _affine(values: gtsam.Values, key: int | None, fixed: np.ndarray) -> np.ndarray:
    return fixed if key is None else np.asarray(values.atVector(key), dtype=float)


class PhotometricFactor(PythonFactor):
    """Photometric residual of one point (its pattern) between its host keyframe and a target.

    Variables: host pose, target pose (``Pose3 T_world_cam``), inverse depth (double), and
    optionally the affine brightness ``(a, b)`` (Vector2) of the host and of the target image.
    Error (P values): ``sqrt(W) * r`` with ``r`` of :func:`factors.photometric.photometric_residuals`.

    Args:
        host_key, target_key, depth_key: keys of the variables.
        camera: intrinsics (of the pyramid level whose images are given).
        host_pixel: (u, v) of the point in the host image.
        host_image, target_image: images with gradients (:class:`factors.photometric.GradientImage`).
        inverse_depth_variance: V of the point (0: W is the constant ``1/(2 sigma_I^2)``).
        sigma_intensity: sigma_I.
        huber_k: Huber threshold on the whitened pattern norm (None: no robust kernel).
        affine_host_key, affine_target_key: keys of affine variables, or None to hold them fixed at
            ``affine_host`` / ``affine_target``.
        pattern: (P, 2) pixel offsets.
        weights: (P,) fixed variance weights W (e.g. evaluated once at the initial values); None
            evaluates W at the current values. Fixed weights keep the cost LM compares equal to
            the one its Gauss-Newton model describes (docs/factors.md §4).
    """

    def __init__(self, host_key: int, target_key: int, depth_key: int, camera: PinholeCamera,
                 host_pixel: ArrayLike, host_image: GradientSampler, target_image: GradientSampler,
                 inverse_depth_variance: float = 0.0, sigma_intensity: float = DEFAULT_SIGMA_INTENSITY,
                 huber_k: float | None = DEFAULT_HUBER_K, affine_host_key: int | None = None,
                 affine_target_key: int | None = None, affine_host: ArrayLike = (0.0, 0.0),
                 affine_target: ArrayLike = (0.0, 0.0), pattern: ArrayLike = PATTERN_DSO8,
                 weights: ArrayLike | None = None) -> None:
        self.camera = camera
        self.pixel = np.asarray(host_pixel, dtype=float).reshape(1, 2)
        self.pattern = np.asarray(pattern, dtype=float).reshape(-1, 2)
        self.host_intensity, self.host_valid = sample_host(host_image, self.pixel, self.pattern)
        self.target_image = target_image
        self.variance = float(inverse_depth_variance)
        self.sigma = float(sigma_intensity)
        self.weights = None if weights is None else np.asarray(weights, dtype=float).reshape(1, -1)
        self.affine_host_key = affine_host_key
        self.affine_target_key = affine_target_key
        self.affine_host = np.asarray(affine_host, dtype=float).reshape(2)
        self.affine_target = np.asarray(affine_target, dtype=float).reshape(2)
        keys = [host_key, target_key, depth_key]
        keys += [k for k in (affine_host_key, affine_target_key) if k is not None]
        self._pose_keys = (host_key, target_key, depth_key)
        super().__init__(robust_unit_noise(self.pattern.shape[0], huber_k), keys)

    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        hk, tk, dk = self._pose_keys
        Twh = values.atPose3(hk)
        Twt = values.atPose3(tk)
        d = values.atDouble(dk)
        ah = _affine(values, self.affine_host_key, self.affine_host)
        at = _affine(values, self.affine_target_key, self.affine_target)
        lin = photometric_residuals(self.camera, self.host_intensity, self.host_valid, self.pixel,
                                    np.array([d]), Twh, Twt, self.target_image, ah, at, self.pattern,
                                    jacobians=H is not None)
        W = variance_weight(lin.J_depth, np.array([self.variance]), self.sigma) if self.weights is None \
            else self.weights
        s = np.sqrt(W)[0]
        if H is not None:
            H[0] = s[:, None] * lin.J_host[0]
            H[1] = s[:, None] * lin.J_target[0]
            H[2] = (s * lin.J_depth[0])[:, None]
            i = 3
            if self.affine_host_key is not None:
                H[i] = s[:, None] * lin.J_affine_host[0]
                i += 1
            if self.affine_target_key is not None:
                H[i] = s[:, None] * lin.J_affine_target[0]
        return s * lin.residual[0]


class StereoFactor(PythonFactor):
    """Left-right photometric residual of one point of a rectified stereo frame (the notes' E_s).

    The point's pixel ``p`` in the left image and its inverse depth ``d`` (hosted in that left
    image) give the right pixel ``p' = (u - fx b d, v)``; the residual is
    ``r = I_R(p') - b_R - exp(a_R - a_L)(I_L(p) - b_L)`` over the pattern, whitened by
    ``sqrt(lambda_stereo * W)`` (the notes' ``E = E_d + lambda E_s``).

    Variables: inverse depth, right affine ``(a_R, b_R)``; optionally the left affine.

    Args:
        depth_key, right_affine_key: keys (right_affine_key None: right affine fixed at
            ``affine_right``).
        camera, baseline: the rectified stereo intrinsics and baseline (metres).
        pixel: (u, v) in the left image.
        left_image, right_image: images with gradients.
        lambda_stereo: the weight lambda of the stereo energy.
        inverse_depth_variance, sigma_intensity, huber_k, pattern: as in :class:`PhotometricFactor`.
        left_affine_key: key of the left image's affine, or None (fixed at ``affine_left``).
        weights: (P,) fixed W (without lambda), or None: W at the current values.
    """

    def __init__(self, depth_key: int, right_affine_key: int | None, camera: PinholeCamera, baseline: float,
                 pixel: ArrayLike, left_image: GradientSampler, right_image: GradientSampler,
                 lambda_stereo: float = 1.0, inverse_depth_variance: float = 0.0,
                 sigma_intensity: float = DEFAULT_SIGMA_INTENSITY, huber_k: float | None = DEFAULT_HUBER_K,
                 left_affine_key: int | None = None, affine_left: ArrayLike = (0.0, 0.0),
                 affine_right: ArrayLike = (0.0, 0.0), pattern: ArrayLike = PATTERN_DSO8,
                 weights: ArrayLike | None = None) -> None:
        if not (np.isfinite(lambda_stereo) and lambda_stereo > 0):
            raise InputError(f"lambda_stereo must be positive, got {lambda_stereo!r}")
        if not (np.isfinite(baseline) and baseline > 0):
            raise InputError(f"stereo baseline must be positive, got {baseline!r}")
        self.camera = camera
        self.baseline = float(baseline)
        self.pixel = np.asarray(pixel, dtype=float).reshape(1, 2)
        self.pattern = np.asarray(pattern, dtype=float).reshape(-1, 2)
        self.left_intensity, self.left_valid = sample_host(left_image, self.pixel, self.pattern)
        self.right_image = right_image
        self.lambda_stereo = float(lambda_stereo)
        self.weights = None if weights is None else np.asarray(weights, dtype=float).reshape(1, -1)
        self.variance = float(inverse_depth_variance)
        self.sigma = float(sigma_intensity)
        self.depth_key = depth_key
        self.right_affine_key = right_affine_key
        self.left_affine_key = left_affine_key
        self.affine_left = np.asarray(affine_left, dtype=float).reshape(2)
        self.affine_right = np.asarray(affine_right, dtype=float).reshape(2)
        keys = [depth_key] + [k for k in (right_affine_key, left_affine_key) if k is not None]
        super().__init__(robust_unit_noise(self.pattern.shape[0], huber_k), keys)

    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        d = values.atDouble(self.depth_key)
        aR = _affine(values, self.right_affine_key, self.affine_right)
        aL = _affine(values, self.left_affine_key, self.affine_left)
        lin = stereo_residuals(self.camera, self.baseline, self.left_intensity, self.left_valid, self.pixel,
                               np.array([d]), self.right_image, aL, aR, self.pattern)
        W = variance_weight(lin.J_depth, np.array([self.variance]), self.sigma) if self.weights is None \
            else self.weights
        s = np.sqrt(self.lambda_stereo * W)[0]
        if H is not None:
            H[0] = (s * lin.J_depth[0])[:, None]
            i = 1
            if self.right_affine_key is not None:
                H[i] = s[:, None] * lin.J_affine_target[0]
                i += 1
            if self.left_affine_key is not None:
                H[i] = s[:, None] * lin.J_affine_host[0]
        return s * lin.residual[0]


class PhotometricBatchFactor(PythonFactor):
    """Photometric residuals of many points with FIXED inverse depths in one target (tracking).

    One Python call evaluates all N x P residuals vectorised, so GTSAM's optimiser pays the
    Values copy once per factor, not once per point. Variables: the target pose, optionally the
    host pose and the affine brightness of host and target. The Huber kernel is applied per point
    on its whitened pattern norm ``|e_n|``, exactly as ``noiseModel.Robust`` does for a
    :class:`PhotometricFactor`: rows are scaled by ``sqrt(w_n)`` (IRLS weight) and one extra
    error entry ``c`` with zero Jacobian, ``c^2 = sum_n 2 rho(|e_n|) - w_n |e_n|^2 >= 0``, makes
    ``0.5 |error|^2`` the true robust cost ``sum_n rho(|e_n|)``. Error dimension N*P + 1.

    Args:
        target_key: target pose key.
        camera: intrinsics of the level.
        pixels: (N, 2) host pixels; inverse_depth (N,) and inverse_depth_variance (N,) fixed.
        host_image, target_image: images with gradients.
        host_key: host pose key, or None to hold the host fixed at ``T_world_host``.
        affine_host_key, affine_target_key: affine keys or None (fixed values).
        sigma_intensity, huber_k, pattern: as in :class:`PhotometricFactor`.
        host_intensity: precomputed :func:`factors.photometric.sample_host` output (then
            ``host_image`` may be None).
        weights: (N, P) fixed variance weights W; None evaluates W at the current values
            (the tracker freezes W per pyramid level so that W does not move with the state).
        bearings: precomputed :func:`factors.photometric.pattern_bearings` of ``pixels``.
        lost_pixel_loss: constant cost of each pattern pixel that is valid in the host (positive
            depth, inside the host image) but invalid in the target at the current values (outside,
            behind); enters ``c`` only (zero Jacobian), so that pushing points out of the image
            does not lower the cost.
    """

    def __init__(self, target_key: int, camera: PinholeCamera, pixels: ArrayLike, inverse_depth: ArrayLike,
                 host_image: GradientSampler, target_image: GradientSampler,
                 inverse_depth_variance: ArrayLike | float = 0.0, host_key: int | None = None,
                 T_world_host: gtsam.Pose3 | None = None, affine_host_key: int | None = None,
                 affine_target_key: int | None = None, affine_host: ArrayLike = (0.0, 0.0),
                 affine_target: ArrayLike = (0.0, 0.0), sigma_intensity: float = DEFAULT_SIGMA_INTENSITY,
                 huber_k: float | None = DEFAULT_HUBER_K, pattern: ArrayLike = PATTERN_DSO8,
                 host_intensity: tuple[np.ndarray, np.ndarray] | None = None,
                 weights: ArrayLike | None = None, bearings: ArrayLike | None = None,
                 lost_pixel_loss: float = 0.0) -> None:
        self.camera = camera
        self.pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
        n = self.pixels.shape[0]
        if n == 0:
            raise InputError("PhotometricBatchFactor needs at least one point")
        self.inverse_depth = np.asarray(inverse_depth, dtype=float).reshape(n)
        self.variance = np.broadcast_to(np.asarray(inverse_depth_variance, dtype=float), (n,)).copy()
        self.pattern = np.asarray(pattern, dtype=float).reshape(-1, 2)
        if host_intensity is None:
            host_intensity = sample_host(host_image, self.pixels, self.pattern)
        self.host_intensity, self.host_valid = host_intensity
        self.target_image = target_image
        self.bearings = pattern_bearings(camera, self.pixels, self.pattern) if bearings is None else bearings
        self.sigma = float(sigma_intensity)
        self.huber_k = huber_k
        self.weights = None if weights is None else np.asarray(weights, dtype=float).reshape(n, self.pattern.shape[0])
        self.target_key, self.host_key = target_key, host_key
        self.T_world_host = gtsam.Pose3() if T_world_host is None else T_world_host
        self.affine_host_key, self.affine_target_key = affine_host_key, affine_target_key
        self.affine_host = np.asarray(affine_host, dtype=float).reshape(2)
        self.affine_target = np.asarray(affine_target, dtype=float).reshape(2)
        keys = [target_key] + [k for k in (host_key, affine_host_key, affine_target_key) if k is not None]
        self.last_valid_points = 0
        self.lost_pixel_loss = float(lost_pixel_loss)
        self._trackable = self.host_valid & (self.inverse_depth > 0)[:, None]
        super().__init__(gtsam.noiseModel.Unit.Create(n * self.pattern.shape[0] + 1), keys)

    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        Twt = values.atPose3(self.target_key)
        Twh = self.T_world_host if self.host_key is None else values.atPose3(self.host_key)
        ah = _affine(values, self.affine_host_key, self.affine_host)
        at = _affine(values, self.affine_target_key, self.affine_target)
        lin = photometric_residuals(self.camera, self.host_intensity, self.host_valid, self.pixels,
                                    self.inverse_depth, Twh, Twt, self.target_image, ah, at, self.pattern,
                                    jacobians=H is not None,
                                    host_jacobians=self.host_key is not None or self.affine_host_key is not None,
                                    bearings=self.bearings)
        W = variance_weight(lin.J_depth, self.variance, self.sigma) if self.weights is None else self.weights
        s = np.sqrt(W)
        e = s * lin.residual
        norm = np.linalg.norm(e, axis=1)
        if self.huber_k is None:
            w = np.ones_like(norm)
            c2 = 0.0
        else:
            w = huber_weight(norm, self.huber_k)
            c2 = float(np.sum(np.maximum(2.0 * huber_loss(norm, self.huber_k) - w * norm * norm, 0.0)))
        self.last_valid_points = int(np.count_nonzero(lin.valid.any(axis=1)))
        if self.lost_pixel_loss > 0:
            c2 += 2.0 * self.lost_pixel_loss * int(np.count_nonzero(self._trackable & ~lin.valid))
        sw = s * np.sqrt(w)[:, None]
        out = np.empty(e.size + 1)
        out[:-1] = (sw * lin.residual).reshape(-1)
        out[-1] = np.sqrt(c2)
        if H is not None:
            def rows(J: np.ndarray) -> np.ndarray:
                M = (sw[..., None] * J).reshape(-1, J.shape[-1])
                return np.vstack([M, np.zeros((1, J.shape[-1]))])
            H[0] = rows(lin.J_target)
            i = 1
            if self.host_key is not None:
                H[i] = rows(lin.J_host)
                i += 1
            if self.affine_host_key is not None:
                H[i] = rows(lin.J_affine_host)
                i += 1
            if self.affine_target_key is not None:
                H[i] = rows(lin.J_affine_target)
        return out
