"""The window solved by GTSAM's Levenberg-Marquardt on the graph of :func:`gtvo.window.problem.build_graph`."""

from __future__ import annotations

import contextlib
import time
from typing import TYPE_CHECKING, Callable, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.smart import shared_residual_passes
from gtvo.core.kernel_threads import kernel_threads
from gtvo.core.keys import affine_key, calibration_key, pose_key, rig_offset_key
from gtvo.core.camera import PinholeCamera
from gtvo.window.covariance import marginals_of_graph
from factors.params import DEFAULT_PHOTOMETRIC, PhotometricConfig
from factors.smart import JacobianBudget
from gtvo.window.config import MarginalPrior, WindowConfig, WindowKeyframe, WindowResult
from gtvo.window.problem import build_graph, visible_targets

if TYPE_CHECKING:
    from gtvo.window.wheel import WheelCalibration

FloatArray = NDArray[np.float64]


def solve_gtsam(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                config: WindowConfig, marginal: MarginalPrior | None = None,
                targets: list[list[int]] | None = None, rig_offset: FloatArray | None = None,
                rig_hold_x: float | None = None, *,
                photometric: PhotometricConfig = DEFAULT_PHOTOMETRIC,
                wheel: "WheelCalibration | None" = None,
                extra_factors: gtsam.NonlinearFactorGraph | None = None,
                on_iteration: Callable[[int, float], None] | None = None,
                jacobian_budget: JacobianBudget | None = None, stack: int = 1) -> WindowResult:
    """Optimise the window with ``gtsam.LevenbergMarquardtOptimizer`` (residuals of the
    ``photometric`` model); updates ``keyframes`` in place.

    ``rig_offset``: the rig offset's current estimate when it is a variable (the result's
    ``rig_offset`` is the optimised one), None: the rectified model; ``rig_hold_x``: its ``delta_x``
    held at this value (:func:`gtvo.window.problem.rig_prior`). ``wheel``: the wheel factors and the
    calibration variable (from ``wheel.estimate``; the result's ``wheel_calibration`` is the
    optimised one; ``wheel`` itself is not changed). ``extra_factors``: native GTSAM
    factors on the keyframes' keys added to the graph (the whole-log refinement's loop edges);
    ``on_iteration(iteration, cost)``: called after every LM iteration (the optimiser then runs
    iteration by iteration, :func:`optimize_by_iterations`; a progress bar, a Ctrl-C check);
    ``jacobian_budget``: the host factors' shared budget of kept Jacobians (the whole-log
    refinement's memory bound, :class:`factors.smart.JacobianBudget`; None: no limit); ``stack``: the
    Python factors in runs of this many per GTSAM factor (:func:`gtvo.window.problem.build_graph`)."""
    t0 = time.perf_counter()
    targets = visible_targets(camera, keyframes, config) if targets is None else targets
    graph, values, hosts = build_graph(camera, baseline, keyframes, config, marginal, targets, rig_offset,
                                       rig_hold_x, photometric=photometric, wheel=wheel,
                                       jacobian_budget=jacobian_budget, stack=stack)
    if extra_factors is not None:
        graph.push_back(extra_factors)
    params = lm_params(config.max_iterations, config.relative_tolerance)
    # the parallel window's worker: the hosts' residuals of each pass at once, on its kernel threads
    together = shared_residual_passes(list(hosts.values())) if kernel_threads() > 1 else contextlib.nullcontext()
    with together:
        opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        initial = opt.error()  # computed by the optimiser at construction: no extra pass
        result = opt.optimize() if on_iteration is None else optimize_by_iterations(opt, params, on_iteration)
        cost = opt.error()
        depths = {h: f.depths_at(result) for h, f in hosts.items()}  # before Marginals relinearises the hosts
        t_cov = time.perf_counter()
        covs = marginals_of_graph(graph, result, [kf.index for kf in keyframes]) if config.covariances else None
        t_cov = time.perf_counter() - t_cov
    for h, d in depths.items():
        keyframes[h].inverse_depth = d
    for kf in keyframes:
        kf.pose = result.atPose3(pose_key(kf.index))
        kf.affine = np.asarray(result.atVector(affine_key(kf.index)), dtype=float).copy()
    n_res = sum(len(keyframes[h]) * len(ts) for h, ts in enumerate(targets))
    rig = None if rig_offset is None else np.asarray(result.atVector(rig_offset_key()), dtype=float).copy()
    calib = None if wheel is None else np.asarray(result.atVector(calibration_key()), dtype=float).copy()
    return WindowResult("gtsam", float(initial), float(cost), int(opt.iterations()), time.perf_counter() - t0, n_res,
                        covs, t_cov if covs is not None else 0.0, rig, calib)


def lm_params(max_iterations: int, relative_tolerance: float) -> gtsam.LevenbergMarquardtParams:
    """The window's LM settings: Marquardt's diagonal damping (lambda scales ``diag(H)``, as the
    hand-rolled solver), no absolute tolerance, lambda up to 1e10."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(relative_tolerance)
    params.setAbsoluteErrorTol(0.0)
    params.setDiagonalDamping(True)
    params.setlambdaUpperBound(1e10)
    return params


def optimize_by_iterations(opt: gtsam.LevenbergMarquardtOptimizer, params: gtsam.LevenbergMarquardtParams,
                           on_iteration: Callable[[int, float], None]) -> gtsam.Values:
    """``opt.optimize()`` one iteration at a time (GTSAM's own loop and stopping rule:
    ``NonlinearOptimizer::defaultOptimize``), calling ``on_iteration(iteration, cost)`` after each."""
    new_error = opt.error()
    while opt.iterations() < params.getMaxIterations():
        current = new_error
        opt.iterate()
        new_error = opt.error()
        on_iteration(int(opt.iterations()), float(new_error))
        if gtsam.checkConvergence(params.getRelativeErrorTol(), params.getAbsoluteErrorTol(), params.getErrorTol(),
                                  current, new_error) or not np.isfinite(current):
            break
    return opt.values()
