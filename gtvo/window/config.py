"""The window's types and settings: :class:`WindowConfig`, :class:`WindowKeyframe`, :class:`MarginalPrior`,
:class:`WindowResult` (keys: :mod:`gtvo.core.keys`' ``pose_key``, ``affine_key`` of the frame index)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.config.sections.window import WindowConfig, WindowSolverName
from gtvo.core.keys import is_pose_key
from factors.params import PhotometricConfig
from factors.photometric import GradientImage
from gtvo.core.camera import PinholeCamera
from gtvo.errors import InputError

if TYPE_CHECKING:
    from gtvo.window.rig import RigOffset
    from gtvo.window.wheel import WheelCalibration

FloatArray = NDArray[np.float64]


def values_subset(values: gtsam.Values, keys: Sequence[int]) -> gtsam.Values:
    out = gtsam.Values()
    for k in keys:
        if is_pose_key(k):
            out.insert(k, values.atPose3(k))
        else:
            out.insert(k, values.atVector(k))
    return out




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
        return np.asarray(self.linearization_point.localCoordinates(values_subset(values, self.keys)).vector(
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
        covariances: frame index -> 6x6 pose covariance at the optimum of every keyframe of the
            window (``WindowConfig.covariances``; None when not computed).
        covariance_seconds: wall time of the covariances (part of ``seconds``).
    """

    solver: str
    initial_cost: float
    cost: float
    iterations: int
    seconds: float
    n_residuals: int
    covariances: dict[int, FloatArray] | None = None
    covariance_seconds: float = 0.0
    #: the rig offset (delta_x, delta_y) after the optimisation (px), None when not estimated
    rig_offset: FloatArray | None = None
    #: the wheel calibration after the optimisation (gtvo.window.wheel), None without wheel odometry
    wheel_calibration: FloatArray | None = None
    #: every variable beyond the keyframes' poses and affines after the optimisation (the rig
    #: offset, the wheel calibration, a caller's: :attr:`gtvo.window.problem.WindowProblem.variables`)
    variables: gtsam.Values | None = None


class WindowState(Protocol):
    """What a back end sees of the window it serves (:class:`gtvo.window.SlidingWindowOptimizer`)."""

    camera: PinholeCamera
    baseline: float | None
    config: WindowConfig
    photometric: PhotometricConfig
    keyframes: list[WindowKeyframe]
    #: the rig offset's one owner (:class:`gtvo.window.rig.RigOffset`), None when not estimated
    rig: "RigOffset | None"
    #: the wheel calibration's one owner (:class:`gtvo.window.wheel.WheelCalibration`), None without wheels
    wheel: "WheelCalibration | None"

    def rig_free_estimate(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """What the window's data say about the rig offset while it is held: ``(estimate, marginal sigmas)``."""

    def rig_x_free_estimate(self) -> tuple[float, float] | None:
        """What the window's data say about ``delta_x`` while it is held: ``(estimate, marginal sigma)``."""
