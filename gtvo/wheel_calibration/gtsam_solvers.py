"""The same calibrations solved by GTSAM: custom factors, Levenberg-Marquardt and Marginals.

* :func:`fit_linear_gtsam` / :func:`fit_diff_drive_gtsam`: one factor per motion pair on one
  calibration variable; the covariance is ``sigma^2 * Marginals(...).marginalCovariance(c)``
  (the graph uses unit noise, so the marginal is ``H^-1``; ``sigma^2 = RSS / (3N - p)`` as in the
  hand-rolled fits).
* :func:`joint_calibration`: a Pose2 graph whose odometry edges pass the raw motion through the
  calibration variable, beside absolute-pose priors and loop closures; it recovers the trajectory
  and X together.
"""

from __future__ import annotations

import contextlib
import re
import time
from dataclasses import dataclass
from typing import Iterable, Iterator, Sequence

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.core.keys import calibration_key, pose_key
from factors.odometry_calibration import (calibrated_odometry_factor, diff_drive_calibration_factor,
                                          linear_calibration_factor)
from gtvo.wheel_calibration.diff_drive import (DiffDriveCalibration, check_diff_drive_observability,
                                         diff_drive_normal_equations)
from gtvo.wheel_calibration.linear import (LinearCalibration, fit_linear, ResidualStatistics, apply_linear, check_linear_observability,
                                     linear_errors, normal_equations)
from gtvo.wheel_calibration.motions import as_motions, integrate_motions, relative_motions
from gtvo.wheel_calibration.observability import DEFAULT_RCOND, analyse_normal_matrix
from gtvo.errors import InputError


def _lm_params(max_iterations: int) -> gtsam.LevenbergMarquardtParams:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-15)
    params.setAbsoluteErrorTol(0.0)
    params.setErrorTol(0.0)
    return params


def _checked_pair(odom: ArrayLike, reference: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    u = as_motions(odom, "odometry motions")
    ref = as_motions(reference, "reference motions")
    if u.shape != ref.shape:
        raise InputError(f"odometry has {u.shape[0]} motions but the reference has {ref.shape[0]}")
    return u, ref


def fit_linear_gtsam(odom: ArrayLike, reference: ArrayLike, max_iterations: int = 100,
                     rcond: float = DEFAULT_RCOND) -> LinearCalibration:
    """Linear calibration X by LM over one :func:`linear_calibration_factor` per motion pair, started at I."""
    u, ref = _checked_pair(odom, reference)
    check_linear_observability(u, rcond)
    key = calibration_key()
    noise = gtsam.noiseModel.Unit.Create(3)
    graph = gtsam.NonlinearFactorGraph()
    for ui, ri in zip(u, ref):
        graph.add(linear_calibration_factor(key, ui, ri, noise))
    initial = gtsam.Values()
    initial.insert(key, np.eye(3).ravel())
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, _lm_params(max_iterations)).optimize()
    x = result.atVector(key)
    stats = ResidualStatistics.from_residuals(linear_errors(x, u, ref), 9)
    cov = stats.sigma2 * gtsam.Marginals(graph, result).marginalCovariance(key)
    h, _ = normal_equations(x, u, ref)
    return LinearCalibration(X=x.reshape(3, 3), covariance=0.5 * (cov + cov.T), residuals=stats,
                             observability=analyse_normal_matrix(h, rcond), solver="gtsam")


def fit_diff_drive_gtsam(odom: ArrayLike, reference: ArrayLike, nominal_baseline: float = 1.0,
                         initial: ArrayLike = (1.0, 1.0, 1.0), max_iterations: int = 100,
                         rcond: float = DEFAULT_RCOND) -> DiffDriveCalibration:
    """Diff-drive calibration ``(k_L, k_R, k_b)`` by LM over one factor per motion pair."""
    u, ref = _checked_pair(odom, reference)
    if not (np.isfinite(nominal_baseline) and nominal_baseline > 0):
        raise InputError(f"nominal baseline must be a positive length, got {nominal_baseline}")
    p0 = np.asarray(initial, dtype=np.float64).reshape(3)
    h0, _, _ = diff_drive_normal_equations(p0, u, ref, nominal_baseline)
    check_diff_drive_observability(h0, u, rcond)
    key = calibration_key()
    noise = gtsam.noiseModel.Unit.Create(3)
    graph = gtsam.NonlinearFactorGraph()
    for ui, ri in zip(u, ref):
        graph.add(diff_drive_calibration_factor(key, ui, ri, nominal_baseline, noise))
    values = gtsam.Values()
    values.insert(key, p0)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, _lm_params(max_iterations))
    result = optimizer.optimize()
    p = result.atVector(key)
    h, _, e = diff_drive_normal_equations(p, u, ref, nominal_baseline)
    obs = check_diff_drive_observability(h, u, rcond)
    stats = ResidualStatistics.from_residuals(e, 3)
    cov = stats.sigma2 * gtsam.Marginals(graph, result).marginalCovariance(key)
    return DiffDriveCalibration(params=p, nominal_baseline=float(nominal_baseline), covariance=0.5 * (cov + cov.T),
                                residuals=stats, observability=obs, iterations=int(optimizer.iterations()),
                                solver="gtsam")


@dataclass(frozen=True)
class PosePrior:
    """An absolute pose measurement ``(x, y, theta)`` of pose ``index`` (GPS-like: give a large heading sigma)."""

    index: int
    pose: tuple[float, float, float]
    sigmas: tuple[float, float, float]


@dataclass(frozen=True)
class LoopClosure:
    """A relative pose measurement ``x_i^-1 x_j = motion`` (e.g. from place recognition / scan matching)."""

    i: int
    j: int
    motion: tuple[float, float, float]
    sigmas: tuple[float, float, float]


@dataclass(frozen=True)
class JointCalibrationResult:
    """Trajectory and calibration from :func:`joint_calibration`."""

    poses: NDArray[np.float64]           # (N+1, 3) x, y, theta
    X: NDArray[np.float64]               # 3x3 (the initial X when ``calibrate`` was False)
    covariance: NDArray[np.float64] | None  # 9x9 marginal covariance of vec(X) (scaled by the noise models)
    iterations: int
    final_error: float
    seconds: float


def piecewise_dead_reckoning(motions: ArrayLike, priors: Sequence[PosePrior]) -> NDArray[np.float64]:
    """Initial poses (N+1, 3): the motions integrated from the latest prior at or before each pose.

    Poses before the first prior are integrated backwards from it. Restarting at every prior keeps
    the drift of a long trajectory bounded, so LM starts near the right minimum.
    """
    u = as_motions(motions)
    n_poses = u.shape[0] + 1
    anchors = sorted({p.index: p for p in priors}.values(), key=lambda p: p.index)
    poses = np.empty((n_poses, 3))
    bounds = [a.index for a in anchors] + [n_poses]
    for a, end in zip(anchors, bounds[1:]):
        poses[a.index:end] = integrate_motions(u[a.index:end - 1], a.pose)[: end - a.index]
    first = anchors[0]
    if first.index > 0:
        # backwards: x_{k} = x_{k+1} (-) u_k, i.e. integrate the inverted motions in reverse order
        inv = np.array([gtsam.Pose2(*m).inverse() for m in u[:first.index][::-1]])
        back = integrate_motions(np.array([[p.x(), p.y(), p.theta()] for p in inv]), first.pose)
        poses[:first.index + 1] = back[::-1]
    return poses


@contextlib.contextmanager
def _indeterminate_as_input_error() -> Iterator[None]:
    """GTSAM's IndeterminateSystemException (a RuntimeError here) as a one-line InputError."""
    try:
        yield
    except RuntimeError as exc:
        if "Indeterminate" not in str(exc):
            raise
        m = re.search(r"Symbol: (\w+)", str(exc))
        near = f" near {m.group(1)}" if m else ""
        raise InputError(f"joint calibration: indeterminate system{near}: the pose priors and loop "
                         "closures do not determine all poses and X") from None


def joint_calibration(raw_motions: ArrayLike, odometry_sigmas: Sequence[float],
                      pose_priors: Iterable[PosePrior] = (), loop_closures: Iterable[LoopClosure] = (),
                      initial_X: ArrayLike | None = None, calibrate: bool = True,
                      calibration_prior_sigma: float | None = None, max_iterations: int = 100,
                      marginals: bool = True, initial_poses: ArrayLike | None = None) -> JointCalibrationResult:
    """Optimise poses x_0..x_N and X given raw odometry, absolute-pose priors and loop closures.

    Each odometry edge is :func:`calibrated_odometry_factor` (measurement ``Pose2(X u_i)``). With
    ``calibrate=False`` X stays fixed at ``initial_X`` and native ``BetweenFactorPose2`` edges on
    ``X u_i`` are used instead (the uncalibrated pose graph, for comparison).

    Initial poses: ``initial_poses`` (N+1, 3) if given; otherwise, when calibrating, the solution of
    the uncalibrated graph (native factors, fast; on long trajectories dead reckoning drifts so far
    that LM from it can stop in a wrong minimum), and then, unless ``initial_X`` is given, X starts
    from the linear fit (:func:`fit_linear`) of the raw motions to that graph's relative motions;
    otherwise :func:`piecewise_dead_reckoning` of the motions ``initial_X u_i``.
    ``calibration_prior_sigma`` optionally adds a prior ``vec(X) ~ vec(initial_X)``.

    With ``marginals`` (default) the marginal covariance of vec(X) is computed; this is also the
    degeneracy check: too little absolute information (e.g. one pose prior) raises InputError. LM
    itself damps an indeterminate system silently, so with ``marginals=False`` that check is skipped.
    """
    u = as_motions(raw_motions, "raw motions")
    x0 = np.eye(3) if initial_X is None else np.asarray(initial_X, dtype=np.float64).reshape(3, 3)
    priors = list(pose_priors)
    closures = list(loop_closures)
    n_poses = u.shape[0] + 1
    for pr in priors:
        if not 0 <= pr.index < n_poses:
            raise InputError(f"pose prior index {pr.index} outside 0..{n_poses - 1}")
    for lc in closures:
        if not (0 <= lc.i < n_poses and 0 <= lc.j < n_poses):
            raise InputError(f"loop closure ({lc.i}, {lc.j}) outside 0..{n_poses - 1}")
    if not priors:
        raise InputError("joint calibration needs at least one absolute pose prior to fix the gauge")
    odo_noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(odometry_sigmas, dtype=np.float64))
    ckey = calibration_key()
    graph = gtsam.NonlinearFactorGraph()
    if calibrate:
        for i, ui in enumerate(u):
            graph.add(calibrated_odometry_factor(pose_key(i), pose_key(i + 1), ckey, ui, odo_noise))
        if calibration_prior_sigma is not None:
            graph.add(gtsam.PriorFactorVector(ckey, x0.ravel(),
                                              gtsam.noiseModel.Isotropic.Sigma(9, calibration_prior_sigma)))
    else:
        for i, vi in enumerate(apply_linear(x0, u)):
            graph.add(gtsam.BetweenFactorPose2(pose_key(i), pose_key(i + 1), gtsam.Pose2(*vi), odo_noise))
    for pr in priors:
        graph.add(gtsam.PriorFactorPose2(pose_key(pr.index), gtsam.Pose2(*pr.pose),
                                         gtsam.noiseModel.Diagonal.Sigmas(np.asarray(pr.sigmas, dtype=np.float64))))
    for lc in closures:
        graph.add(gtsam.BetweenFactorPose2(pose_key(lc.i), pose_key(lc.j), gtsam.Pose2(*lc.motion),
                                           gtsam.noiseModel.Diagonal.Sigmas(np.asarray(lc.sigmas, dtype=np.float64))))
    x_start = x0
    if initial_poses is None and calibrate:
        initial_poses = joint_calibration(u, odometry_sigmas, priors, closures, x0, calibrate=False,
                                          max_iterations=max_iterations).poses
        if initial_X is None:
            # the linear fit of the raw motions against the uncalibrated graph's relative motions
            try:
                x_start = fit_linear(u, relative_motions(initial_poses)).X
            except InputError:
                x_start = x0
    values = gtsam.Values()
    if initial_poses is not None:
        start = np.asarray(initial_poses, dtype=np.float64)
        if start.shape != (n_poses, 3):
            raise InputError(f"initial poses: expected shape ({n_poses}, 3), got {start.shape}")
        for i, p in enumerate(start):
            values.insert(pose_key(i), gtsam.Pose2(*p))
    else:
        for i, p in enumerate(piecewise_dead_reckoning(apply_linear(x0, u), priors)):
            values.insert(pose_key(i), gtsam.Pose2(*p))
    if calibrate:
        values.insert(ckey, x_start.ravel())
    t0 = time.perf_counter()
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, _lm_params(max_iterations))
    with _indeterminate_as_input_error():
        result = optimizer.optimize()
    seconds = time.perf_counter() - t0
    poses = np.array([[p.x(), p.y(), p.theta()] for p in (result.atPose2(pose_key(i)) for i in range(n_poses))])
    x = result.atVector(ckey).reshape(3, 3) if calibrate else x0
    cov = None
    if calibrate and marginals:
        with _indeterminate_as_input_error():
            cov = gtsam.Marginals(graph, result).marginalCovariance(ckey)
    return JointCalibrationResult(poses=poses, X=x, covariance=cov, iterations=int(optimizer.iterations()),
                                  final_error=float(graph.error(result)), seconds=seconds)
