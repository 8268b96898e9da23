"""The tracker's data: its settings (:class:`TrackingConfig`), a keyframe prepared for tracking
(:class:`TrackingKeyframe`: pyramid samples of its points, with the photometric model it is
tracked with), and what tracking a frame gives (:class:`TrackingResult`, with the pose
covariance). The solvers: :mod:`gtvo.frontend.tracking`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.params import PhotometricConfig
from factors.photometric import DEFAULT_CLIP_RANGE, GradientImage, pattern_bearings, sample_host
from gtvo.core.camera import PinholeCamera
from gtvo.config.sections.tracking import TrackingConfig
from gtvo.errors import InputError, TrackingFailure
from gtvo.core.image import build_pyramid


@dataclass(frozen=True)
class PointResiduals:
    """The tracker's photometric residuals at its solution (level 0), per keyframe point the frame sees.

    Attributes:
        index: (M,) the points' positions among the keyframe's points.
        pixels: (M, 2) where the frame sees them (their valid pattern pixels' warps less their pattern offsets, averaged).
        residual: (M,) the RMS over their valid pattern pixels of
            ``r = I_frame(w) - b - exp(a - a_kf) (I_kf - b_kf)`` (grey levels, before weights).
    """

    index: NDArray[np.intp]
    pixels: NDArray[np.float64]
    residual: NDArray[np.float64]


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
        relative_rms: ``rms`` over the whitened RMS that an image unrelated to the keyframe, of the
            same contrast, would leave: ``sqrt(2 Var(I_kf) mean(W))`` over the valid pattern pixels
            (two independent draws differ by ``2 Var`` in the mean square). Independent of
            ``sigma_intensity``; about 0.2 on the real logs, 0.5 and more where the images do not
            determine the pose (docs/tracking.md, "Dark and flat images"). NaN when not computed.
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
    relative_rms: float = float("nan")

    @property
    def rotation_sigma_deg(self) -> float:
        """Standard deviation of the rotation along its worst-determined axis (degrees)."""
        return largest_sigma(self.covariance[:3, :3], np.degrees(1.0))

    @property
    def translation_sigma_m(self) -> float:
        """Standard deviation of the translation along its worst-determined axis (metres)."""
        return largest_sigma(self.covariance[3:, 3:], 1.0)

    def raise_if_failed(self) -> "TrackingResult":
        """Return self, or raise :class:`TrackingFailure` with the reason."""
        if not self.success:
            raise TrackingFailure(self.reason)
        return self


def largest_sigma(cov: NDArray[np.float64], scale: float) -> float:
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
        config: tracker settings (levels, iterations, failure checks).
        pyramid: the image's :func:`frame_pyramid` with ``config.levels`` and ``photometric.clip_range``
            when the caller has it already (a tracked frame that becomes a keyframe); None: built here.
        photometric: the photometric model (pattern, noise, Huber threshold, clipped range; a VO
            run's ``OdometryConfig.photometric``); default :class:`factors.params.PhotometricConfig`'s.

    Attributes:
        pattern: ``photometric.pattern`` as a (P, 2) array.
    """

    def __init__(self, camera: PinholeCamera, image: ArrayLike, pixels: ArrayLike, inverse_depth: ArrayLike,
                 inverse_depth_variance: ArrayLike, affine: ArrayLike = (0.0, 0.0),
                 config: TrackingConfig | None = None, pyramid: Sequence[GradientImage] | None = None,
                 photometric: PhotometricConfig | None = None) -> None:
        self.config = config or TrackingConfig()
        self.photometric = photometric or PhotometricConfig()
        self.pattern = self.photometric.pattern_array
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
        if pyramid is not None and not (len(pyramid) and pyramid[0].image.shape == img.shape
                                        and pyramid[0].clip_range == self.photometric.clip_range):
            raise InputError("TrackingKeyframe: the given pyramid is not the image's with the tracker's clip range")
        pyr = [g.image for g in pyramid] if pyramid is not None else build_pyramid(img, self.config.levels)
        self.levels = len(pyr)
        self.cameras = [camera.scaled(lv) for lv in range(self.levels)]
        pat = self.pattern
        self.level_index: list[NDArray[np.intp]] = []
        self.level_pixels: list[NDArray[np.float64]] = []
        self.level_bearings: list[NDArray[np.float64]] = []
        self.host_samples: list[tuple[NDArray, NDArray]] = []
        #: per level, laid out once for the tracker's hot loop: the points' inverse depths and
        #: variances (C-contiguous) and the host samples whose point has a positive inverse depth
        #: (a pattern pixel lost in the frame costs only where one of these is invalid)
        self.level_inverse_depth: list[NDArray[np.float64]] = []
        self.level_variance: list[NDArray[np.float64]] = []
        self.level_countable: list[NDArray[np.bool_]] = []
        for lv in range(self.levels):
            step = max(1, int(np.ceil(self.config.coarse_decay ** lv)))
            step = min(step, max(1, n // max(1, self.config.min_coarse_points)))
            idx = np.arange(0, n, step)
            lp = (px[idx] + 0.5) / 2.0 ** lv - 0.5
            self.level_index.append(idx)
            self.level_pixels.append(lp)
            self.level_bearings.append(pattern_bearings(self.cameras[lv], lp, pat))
            level = pyramid[lv] if pyramid is not None else GradientImage(pyr[lv], clip_range=self.photometric.clip_range)
            Ih, hv = sample_host(level, lp, pat)  # laid out once for the compiled residuals
            self.host_samples.append((np.ascontiguousarray(Ih, dtype=float), np.ascontiguousarray(hv, dtype=bool)))
            self.level_inverse_depth.append(np.ascontiguousarray(d[idx]))
            self.level_variance.append(np.ascontiguousarray(V[idx]))
            self.level_countable.append(self.host_samples[-1][1] & (d[idx] > 0)[:, None])


def frame_pyramid(image: ArrayLike, levels: int,
                  clip_range: tuple[float, float] | None = DEFAULT_CLIP_RANGE) -> list[GradientImage]:
    """The frame's pyramid with gradients, one :class:`GradientImage` per level (``clip_range``:
    the keyframe's, ``TrackingKeyframe.photometric.clip_range``)."""
    return [GradientImage(p, clip_range=clip_range) for p in build_pyramid(np.asarray(image, dtype=np.float32), levels)]
