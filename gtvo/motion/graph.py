"""The factor-graph twin of the Kalman filter: assemble and solve (:mod:`factors.motion`).

The graph over states ``v0 .. v{N-1}`` holds the prior on ``v0``, one pose measurement factor per
state and one process factor between consecutive states. Its solution is the smoothed posterior
(equal to :func:`gtvo.motion.model.rts_smooth`), and the marginal of the last state is the
filter's final estimate. The graph is linear: angles are not wrapped, so it agrees with the
(wrapping) filter as long as no measurement or state crosses +-pi.
"""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.core.keys import motion_state_key
from factors.motion import pose_measurement_factor, process_factor, state_prior_factor
from gtvo.errors import InputError
from gtvo.motion.model import STATE_DIM, MotionNoiseConfig, _check_prior


def build_motion_graph(measurements: ArrayLike, times: ArrayLike, prior_mean: ArrayLike, prior_cov: ArrayLike,
                       noise: MotionNoiseConfig = MotionNoiseConfig()) -> gtsam.GaussianFactorGraph:
    """The linear-Gaussian graph of the same problem :func:`gtvo.motion.model.filter_sequence` solves."""
    z = np.asarray(measurements, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if z.ndim != 2 or z.shape[1] != 3 or z.shape[0] == 0 or t.shape != (z.shape[0],):
        raise InputError(f"measurements must be (N, 3) with N >= 1 and one time each, got {z.shape} and {t.shape}")
    if not (np.all(np.isfinite(z)) and np.all(np.isfinite(t))) or np.any(np.diff(t) <= 0):
        raise InputError("measurements and times must be finite and times strictly increasing")
    mean, cov = _check_prior(prior_mean, prior_cov)
    graph = gtsam.GaussianFactorGraph()
    graph.add(state_prior_factor(motion_state_key(0), mean, cov))
    for i in range(z.shape[0]):
        if i > 0:
            graph.add(process_factor(motion_state_key(i - 1), motion_state_key(i), t[i] - t[i - 1], noise.accel_sigmas))
        graph.add(pose_measurement_factor(motion_state_key(i), z[i], noise.measurement_sigmas))
    return graph


def solve_motion_graph(graph: gtsam.GaussianFactorGraph, n_states: int,
                       marginal_states: tuple[int, ...] = ()) -> tuple[NDArray[np.float64], dict[int, NDArray[np.float64]]]:
    """Solve the graph: all state means (N, 6) and the marginal covariances of ``marginal_states``.

    The chain is eliminated from the last state back to ``v0``. Measured: with the process
    factors' constrained rows, GTSAM's weighted Gram-Schmidt loses about 1e-9 (relative 3e-10)
    on the velocities when it eliminates forwards (``v0`` first, also what COLAMD picks for a
    chain) on chains of 40+ states, and stays at 1e-13 in this order (docs/motion_model.md).
    """
    ordering = gtsam.Ordering()
    for i in range(n_states - 1, -1, -1):
        ordering.push_back(motion_state_key(i))
    solution = graph.optimize(ordering)
    means = np.array([solution.at(motion_state_key(i)) for i in range(n_states)]).reshape(n_states, STATE_DIM)
    covs: dict[int, NDArray[np.float64]] = {}
    if marginal_states:
        marginals = gtsam.Marginals(graph, solution)
        covs = {int(i): np.asarray(marginals.marginalCovariance(motion_state_key(i))) for i in marginal_states}
    return means, covs
