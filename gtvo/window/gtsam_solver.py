"""The window solved by GTSAM's Levenberg-Marquardt on the graph of :func:`gtvo.window.problem.build_graph`."""

from __future__ import annotations

import contextlib
import time
from typing import Callable

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.smart import shared_residual_passes
from gtvo.core.kernel_threads import kernel_threads
from gtvo.core.keys import affine_key, calibration_key, pose_key, rig_offset_key
from gtvo.window import residual_memo
from gtvo.window.covariance import marginals_of_graph
from gtvo.window.config import WindowResult, values_subset
from gtvo.window.problem import WindowProblem, build_graph, vector_of

FloatArray = NDArray[np.float64]


def solve_gtsam(problem: WindowProblem) -> WindowResult:
    """Optimise the window ``problem`` with ``gtsam.LevenbergMarquardtOptimizer`` on its graph
    (:func:`gtvo.window.problem.build_graph`); updates the problem's keyframes in place.

    The result's ``rig_offset`` and ``wheel_calibration`` are the optimised rig offset and wheel
    calibration (None when the problem has none; the problem's sensors are not changed), its
    ``variables`` every variable beyond the keyframes' poses and affines. With the settings'
    ``on_iteration`` the optimiser runs iteration by iteration (:func:`optimize_by_iterations`)."""
    t0 = time.perf_counter()
    keyframes, config = problem.keyframes, problem.config
    graph, values, hosts = build_graph(problem)
    params = lm_params(config.max_iterations, config.relative_tolerance)
    on_iteration = problem.settings.on_iteration
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
    if problem.settings.keep_residuals and problem.settings.jacobian_budget is None:  # for the next pass there
        for h, f in hosts.items():
            kept = f.kept_residuals(result, depths[h])
            if kept is not None:
                state = residual_memo.HostState(kept[0], kept[1], depths[h], kept[2])
                residual_memo.remember(f.points, keyframes[h].image, state, kept[3])
    for h, d in depths.items():
        keyframes[h].inverse_depth = d
    for kf in keyframes:
        kf.pose = result.atPose3(pose_key(kf.index))
        kf.affine = np.asarray(result.atVector(affine_key(kf.index)), dtype=float).copy()
    variables = values_subset(result, list(problem.variables.keys()))
    return WindowResult("gtsam", float(initial), float(cost), int(opt.iterations()), time.perf_counter() - t0,
                        problem.n_residuals(), covs, t_cov if covs is not None else 0.0,
                        vector_of(variables, rig_offset_key()), vector_of(variables, calibration_key()), variables)


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
