"""The window's types and settings: :class:`WindowConfig`, :class:`WindowKeyframe`, :class:`MarginalPrior`,
:class:`WindowResult` (keys: :mod:`gtvo.core.keys`' ``pose_key``, ``affine_key`` of the frame index)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal, Protocol, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.keys import is_pose_key
from factors.params import PhotometricConfig
from factors.photometric import GradientImage
from gtvo.core.camera import PinholeCamera
from gtvo.core.settings import SettingError, check_settings, setting
from gtvo.errors import InputError, show

if TYPE_CHECKING:
    from gtvo.window.rig import RigOffset
    from gtvo.window.wheel import WheelCalibration

FloatArray = NDArray[np.float64]
WindowSolverName = Literal["gtsam", "handrolled"]


def values_subset(values: gtsam.Values, keys: Sequence[int]) -> gtsam.Values:
    out = gtsam.Values()
    for k in keys:
        if is_pose_key(k):
            out.insert(k, values.atPose3(k))
        else:
            out.insert(k, values.atVector(k))
    return out


@dataclass(frozen=True)
class WindowConfig:
    """Settings of the window (defaults follow DSO where DSO has one; its photometric model, the
    noise of the weight ``W``, the Huber threshold and the pattern, is the
    :class:`factors.params.PhotometricConfig` the :class:`gtvo.window.SlidingWindowOptimizer` is given).

    Attributes:
        size: keyframes in the window (DSO: 7).
        lambda_stereo: weight of the host's stereo energy ``lambda E_s`` (the notes'
            ``E = E_d + lambda E_s``); 1 treats a left-right residual like a temporal one: both
            compare two images of the same sensor type with the same noise.
        affine_sigma: ``(sigma_a, sigma_b)`` of the prior of each keyframe's affine brightness
            around its tracked value. DSO without photometric calibration leaves ``(a, b)`` free;
            (1.0 log gain, 100 grey levels) is a weak prior that only keeps the system regular.
        acceleration_sigma: ``(angular rad/s^2, linear m/s^2)`` of the motion-smoothness prior, a
            :class:`factors.smoothness.ConstantVelocityFactor` on every three consecutive
            keyframes that have timestamps; None: no motion prior. The defaults are weak (a car
            brakes at up to ~8 m/s^2, a hand-held camera turns faster): with images that fix the
            poses the prior moves nothing; it keeps a window defined when they do not.
        gauge_sigma: sigma (rad, m; log gain, grey levels) of the gauge prior that fixes the oldest
            keyframe's pose and affine while no marginalisation prior exists.
        min_visible_points, min_visible_fraction: a keyframe is a target of a host when at least
            this many (and this fraction) of the host's points project into it, in front of it.
        max_iterations: LM iterations per window optimisation (DSO allows up to 6 per new keyframe;
            on KITTI 4 or 6 moved the ATE by < 1 mm for 33-82 % more time: docs/benchmarks.md,
            "Point density").
        relative_tolerance: stop when an iteration lowers the cost by less than this fraction.
        optimize_every: the window's optimisation may wait until this many keyframes have joined
            it (1: after each) while no frame was tracked against the last keyframe (keyframes at
            every frame: a car at 10 Hz) and the new keyframe's stereo depth error moves its points
            by less than the residual pattern's radius over one step; otherwise, for a keyframe not
            made from a successful track and with the fixed-lag backend it runs at once, and
            :meth:`gtvo.odometry.VisualOdometry.finish` runs it for those still waiting at the
            end. On KITTI_sequence_1 at 10 Hz 2 (the default) halves the optimisations at the same
            ATE; at 5 and 3.3 Hz, and on logs with frames between keyframes, nothing waits
            (docs/window.md, "When the window is optimised").
        marginalize: keep leaving keyframes' information as a prior (False: simply drop them).
        backend: ``"lm"``: each window optimised by a solver (:func:`solve_gtsam` or
            :func:`solve_handrolled`) and leaving keyframes marginalised by :func:`marginalize`;
            ``"fixed_lag"``: a ``gtsam.IncrementalFixedLagSmoother`` (iSAM2) holds the window,
            the keyframe's sequence number as timestamp and lag ``size - 0.5``, and marginalises
            leaving keyframes itself (docs/window.md, "Fixed-lag backend").
        covariances: after each optimisation, keep every keyframe's 6x6 pose covariance at the
            optimum (:mod:`gtvo.window.covariance`; docs/window.md, "Pose covariances"); False: none
            are computed (no cost).
        rig_calibration: stereo odometry estimates the right image's rectification error
            ``(delta_x, delta_y)`` (px) online as a window variable (docs/window.md, "Rig
            calibration"; LM backend only; RGB-D input has no rig). It is used by
            :class:`gtvo.odometry.VisualOdometry`; a :class:`gtvo.window.SlidingWindowOptimizer`
            estimates it when given a ``rig_offset``. True (the default): while neither offset is
            significant (the first pair's vertical one, then a full window's test of both every
            ``size`` windows, 3 error bars) the window solves the rectified model, exactly as
            False; once either is, both are estimated. False: the rectified model throughout.
        rig_offset_sigma: sigma (px) of the zero-mean prior on the rig offset, set once (with the
            gauge prior); afterwards the marginalisation prior carries what the window learnt.
        parallel: in :class:`gtvo.odometry.VisualOdometry`, the window runs in a worker process
            beside the front end (the second core), and the front end applies the window's result
            of its ``n``-th keyframe once it has sent keyframe ``n + 2`` (at once when the next
            frames should not track against its stereo depths): the same answer in every
            run, a little different from the sequential order (False), in which every keyframe
            waits for its window (docs/window.md, "The window beside the tracker"). ``gtvo run
            --no-parallel`` turns it off; ``gtvo batch`` turns it off unless its config asks.
        worker_threads: threads the parallel window's worker runs its compiled kernels on (the
            hosts' residuals of each LM pass at once, docs/window.md, "Kernel threads in the
            worker"): the results are the same, to the bit, for any number. None (the default):
            1 (on the idle 2-core machine two gave the same frames/s for more CPU, the GIL-held
            Python between the kernels being the worker's limit: docs/benchmarks.md); ``gtvo
            batch`` jobs keep one core per log (1) unless their config asks. Without
            ``parallel`` the window runs in the caller's thread alone.
    """

    size: int = setting(7, "[2, 100]")
    lambda_stereo: float = setting(1.0, "(0, 1000]")
    affine_sigma: tuple[float, float] = setting((1.0, 100.0), "(0, 1000000]")
    acceleration_sigma: tuple[float, float] | None = setting((1.0, 2.0), "(0, 1000000]")
    gauge_sigma: float = setting(1e-6, "[1e-9, 1]")
    min_visible_points: int = setting(30, "[0, 100000]")
    min_visible_fraction: float = setting(0.1, "[0, 1]")
    max_iterations: int = setting(3, "[1, 1000]")
    relative_tolerance: float = setting(1e-4, "[0, 1]")
    optimize_every: int = setting(2, "[1, 100]")
    marginalize: bool = True
    backend: Literal["lm", "fixed_lag"] = "lm"
    covariances: bool = True
    rig_calibration: bool = True
    rig_offset_sigma: float = setting(2.0, "[0.01, 100]")
    parallel: bool = False
    worker_threads: int | None = setting(None, "[1, 16]")

    def __post_init__(self) -> None:
        check_settings(self)  # backend and the ranges declared above
        if self.worker_threads is not None and (isinstance(self.worker_threads, bool)
                                                or not isinstance(self.worker_threads, int)):
            raise SettingError("worker_threads", f"must be a whole number, got {show(self.worker_threads)}")
        for name in ("affine_sigma", "acceleration_sigma"):
            value = getattr(self, name)
            if value is not None and len(value) != 2:
                raise SettingError(name, f"must be two numbers, got {show(value)}")


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
