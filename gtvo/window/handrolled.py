"""The window solved by a hand-rolled Levenberg-Marquardt on the reduced camera system.

Poses and affines are the unknowns of the reduced system; inverse depths are eliminated by the
Schur complement per host and recovered by back-substitution (docs/window.md). Each host's
linearisation is :class:`factors.host_points.HostPoints`, the same object that
:class:`factors.smart.HostPointsFactor` hands GTSAM; the Levenberg-Marquardt loop here is this
solver's own. It minimises the same cost as :mod:`gtvo.window.gtsam_solver`, and the tests
compare the two.
"""

from __future__ import annotations

import time
from typing import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.host_points import DepthSystem, HostPoints
from gtvo.core.keys import affine_key, calibration_key, pose_key, rig_offset_key
from gtvo.core.timing import stage, timed
from gtvo.window import residual_memo
from gtvo.window.covariance import marginals_of_hessian
from gtvo.window.config import MarginalPrior, WindowResult
from gtvo.window.problem import WindowProblem, host_samples, vector_of

FloatArray = NDArray[np.float64]


# ----------------------------------------------------------------------------------------------
# hand-rolled solver: reduced camera system


class _WindowHost:
    """One host of the hand-rolled solver: its :class:`factors.host_points.HostPoints` (the same
    linearisation as :class:`factors.smart.HostPointsFactor`'s) and where its blocks sit in the
    window's state (8 entries per keyframe: pose, then affine; with the rig variable the rig
    offset's 2 entries after all keyframes').

    W is frozen at the window's starting state, where the host is built, as the smart factor
    does at its first evaluation, so both solvers minimise the same fixed cost.
    """

    @timed("window_build")  # the host's set-up (its first residuals: "linearisation")
    def __init__(self, problem: WindowProblem, h: int) -> None:
        keyframes, config, photometric = problem.keyframes, problem.config, problem.settings.photometric
        rig_offset = problem.rig_offset
        kh = keyframes[h]
        self.h, self.targets = h, list(problem.targets[h])
        self.image = kh.image  # the host's image: its residuals are kept by it
        self.points = HostPoints(problem.camera, kh.pixels, kh.image, [keyframes[t].image for t in self.targets],
                                 kh.variance, kh.prior_inverse_depth, sigma_intensity=photometric.sigma_intensity,
                                 huber_k=photometric.huber_k, pattern=photometric.pattern_array,
                                 depth_prior=kh.depth_prior,
                                 right_image=kh.right, baseline=problem.baseline, lambda_stereo=config.lambda_stereo,
                                 stereo_affine=kh.stereo_affine, rig=rig_offset is not None,
                                 host_samples=host_samples(problem.camera, kh, photometric.pattern_array))
        K = len(keyframes)
        self.rig_columns = np.arange(8 * K, 8 * K + 2) if self.points.rig else None
        # blocks [host pose, host affine, target pose, target affine]: 8 per keyframe
        self.columns = [np.r_[8 * h:8 * h + 8, 8 * t:8 * t + 8] for t in self.targets]
        poses, affines = self._local([k.pose for k in keyframes], [k.affine for k in keyframes])
        offset = rig_offset if self.points.rig else None  # the stereo term's (its residuals kept by that key)
        # the residuals an earlier pass computed at this state (gtvo.window.residual_memo), else a pass
        lins = residual_memo.recall(self.points, kh.image,
                                    residual_memo.HostState(poses, affines, kh.inverse_depth, offset))
        if lins is None:
            lins = self.points.residuals(poses, affines, kh.inverse_depth, offset=rig_offset)
        #: (E, lins) at the window's starting state (W frozen there): the initial cost and the first linearisation
        self.start = (float(self.points.point_costs(lins, kh.inverse_depth).sum()), lins)

    def remember(self, state: "_State", d: FloatArray, lins: list) -> None:
        """Keep ``lins``, this host's residuals at ``state`` with inverse depths ``d``, for the next
        pass there (:func:`gtvo.window.residual_memo.remember`)."""
        P, A = self._local(state.poses, state.affines)
        offset = state.vectors.get(rig_offset_key()) if self.points.rig else None
        residual_memo.remember(self.points, self.image, residual_memo.HostState(P, A, d, offset), lins)

    def _local(self, poses: Sequence, affines: Sequence) -> tuple[list, list]:
        """The host's and its targets' poses and affines, in :class:`HostPoints`' order."""
        idx = [self.h] + self.targets
        return [poses[i] for i in idx], [affines[i] for i in idx]

    def linearize(self, d: FloatArray, H: FloatArray, g: FloatArray, lins: list) -> DepthSystem:
        """Add this host's reduced Gauss-Newton terms (depths eliminated) to the window's ``H``, ``g``;
        ``lins``: the residuals at this state (:meth:`evaluate_safeguarded`'s or :attr:`start`'s)."""
        return self.points.linearize(lins, d, H, g, self.columns, self.rig_columns)

    def evaluate_safeguarded(self, state: "_State", system: DepthSystem, d_new: FloatArray
                             ) -> tuple[float, FloatArray, list]:
        """The cost at a trial ``state`` with the back-substituted inverse depths ``d_new``, except for
        points whose cost rose above their cost at ``system``'s linearisation point and that cost
        less at their depth there, which keep it (the safeguarded depth step, as the smart factor's):
        ``(cost, depths, linearisations)``."""
        P, A = self._local(state.poses, state.affines)
        offset = state.vectors.get(rig_offset_key())
        c, d, lins = self.points.safeguard(P, A, system, d_new, self.points.residuals(P, A, d_new, offset=offset),
                                           offset)
        return float(c.sum()), d, lins


class _State:
    """A state of the hand-rolled solver: the keyframes' poses and affines (8 entries each, in
    order) and the problem's vector variables (:func:`_vector_columns`: the rig offset, the wheel
    calibration, then a caller's, after the keyframes' entries)."""

    def __init__(self, problem: WindowProblem, poses: list, affines: list, vectors: dict[int, FloatArray]) -> None:
        self.problem, self.poses, self.affines, self.vectors = problem, poses, affines, vectors

    @classmethod
    def start(cls, problem: WindowProblem) -> "_State":
        """The problem's starting state."""
        vectors = {key: np.asarray(problem.variables.atVector(key), dtype=float).copy()
                   for key in _vector_columns(problem)}
        return cls(problem, [kf.pose for kf in problem.keyframes], [kf.affine.copy() for kf in problem.keyframes],
                   vectors)

    def retract(self, dx: FloatArray) -> "_State":
        """The state moved by ``dx`` (poses on the right, the rest added)."""
        cols = _vector_columns(self.problem)
        return _State(self.problem, [p.retract(dx[8 * k:8 * k + 6]) for k, p in enumerate(self.poses)],
                      [a + dx[8 * k + 6:8 * k + 8] for k, a in enumerate(self.affines)],
                      {key: v + dx[cols[key][0]:cols[key][0] + cols[key][1]] for key, v in self.vectors.items()})

    def values(self) -> gtsam.Values:
        """The state as GTSAM ``Values``."""
        values = gtsam.Values()
        for k, kf in enumerate(self.problem.keyframes):
            values.insert(pose_key(kf.index), self.poses[k])
            values.insert(affine_key(kf.index), self.affines[k])
        for key, v in self.vectors.items():
            values.insert(key, np.asarray(v, dtype=float))
        return values


def _vector_columns(problem: WindowProblem) -> dict[int, tuple[int, int]]:
    """Vector variable key -> (first column, size) in the hand-rolled state: after the keyframes'
    8 entries each, the rig offset, the wheel calibration, then the others in key order."""
    keys = list(problem.variables.keys())
    first = [k for k in (rig_offset_key(), calibration_key()) if k in keys]
    out, at = {}, 8 * len(problem.keyframes)
    for key in first + [k for k in keys if k not in first]:
        n = int(np.asarray(problem.variables.atVector(key)).size)
        out[key] = (at, n)
        at += n
    return out


def _state_columns(problem: WindowProblem) -> dict[int, tuple[int, int]]:
    """Key -> (first column, size) in the hand-rolled state, for every variable."""
    pos = {pose_key(kf.index): (8 * k, 6) for k, kf in enumerate(problem.keyframes)}
    pos.update({affine_key(kf.index): (8 * k + 6, 2) for k, kf in enumerate(problem.keyframes)})
    pos.update(_vector_columns(problem))
    return pos


def _marginal_terms(marginal: MarginalPrior | None, state: _State, H=None, g=None) -> float:
    """The marginalisation prior's cost, and (given H, g) its terms (Jacobian of delta taken as I,
    as ``gtsam.LinearContainerFactor`` does)."""
    if marginal is None:
        return 0.0
    dl = marginal.delta(state.values())
    if H is not None:
        pos = _state_columns(state.problem)
        idx = np.concatenate([np.arange(pos[key][0], pos[key][0] + dim) for key, dim in zip(marginal.keys, marginal.dims)])
        H[np.ix_(idx, idx)] += marginal.H
        g[idx] += marginal.H @ dl - marginal.eta
    return float(0.5 * dl @ marginal.H @ dl - marginal.eta @ dl + 0.5 * marginal.f)


def _graph_terms(state: _State, H=None, g=None) -> float:
    """The problem's non-host factors (:attr:`WindowProblem.factors`: priors, motion prior, rig
    prior, wheel factors, loop edges, a caller's): their cost, and (given H, g) their Gauss-Newton
    terms from the graph's own linearisation (``graph.linearize(values)``: a ``JacobianFactor``
    is ``0.5 |A dx - b|^2``, GTSAM's right-perturbation tangent, as the poses' retraction here)."""
    factors = state.problem.factors
    if factors.size() == 0:
        return 0.0
    values = state.values()
    if H is not None:
        pos = _state_columns(state.problem)
        linear = factors.linearize(values)
        for i in range(linear.size()):
            factor = linear.at(i)
            idx = np.concatenate([np.arange(pos[key][0], pos[key][0] + pos[key][1]) for key in factor.keys()])
            if isinstance(factor, gtsam.HessianFactor):
                H[np.ix_(idx, idx)] += factor.information()
                g[idx] -= np.asarray(factor.linearTerm(), dtype=float).reshape(-1)
            else:
                A, b = factor.jacobian()
                H[np.ix_(idx, idx)] += A.T @ A
                g[idx] -= A.T @ b
    return float(factors.error(values))


def _terms(problem: WindowProblem, state: _State, H=None, g=None) -> float:
    """Every term but the hosts': the problem's graph, then the marginalisation prior."""
    return _graph_terms(state, H, g) + _marginal_terms(problem.marginal, state, H, g)


def window_cost(problem: WindowProblem) -> float:
    """The window cost E at the problem's starting state, computed the hand-rolled way (W at this state)."""
    hosts = [_WindowHost(problem, h) for h in range(len(problem.targets))]
    E = sum(host.start[0] for host in hosts)
    return E + _terms(problem, _State.start(problem))


def solve_handrolled(problem: WindowProblem) -> WindowResult:
    """Levenberg-Marquardt on the reduced camera system; updates the problem's keyframes in place.
    The result and the settings' ``on_iteration`` as :func:`gtvo.window.solve_gtsam`'s.

    The state: 8 entries per keyframe (pose, affine), then the problem's vector variables (the rig
    offset's 2, the wheel calibration's, a caller's: :func:`_vector_columns`). The host factors'
    terms come from their own kernels (:class:`_WindowHost`), every other factor's from the
    problem's graph linearised by GTSAM (:func:`_graph_terms`), the marginalisation prior's as it is.

    Per iteration: every host's Gauss-Newton blocks over (poses, affines) ``x`` (8 per keyframe)
    and its inverse depths ``d`` (diagonal ``H_dd``), the Schur complement
    ``H_red = H_xx - sum_n H_xd H_xd^T / H_dd``, ``g_red = g_x - sum_n H_xd g_d / H_dd``, the
    damped step ``(H_red + lambda diag(H_red)) dx = -g_red`` and the back-substitution
    ``dd = -(g_d + H_xd^T dx) / H_dd``; the step is kept when the true cost decreases.
    """
    t0 = time.perf_counter()
    keyframes, config, on_iteration = problem.keyframes, problem.config, problem.settings.on_iteration
    hosts = [_WindowHost(problem, h) for h, ts in enumerate(problem.targets) if ts]
    state = _State.start(problem)
    M = 8 * len(keyframes) + sum(n for _, n in _vector_columns(problem).values())
    depths = {host.h: keyframes[host.h].inverse_depth.copy() for host in hosts}

    def cost(trial: _State, D_new, systems) -> tuple[float, dict[int, FloatArray], dict[int, list]]:
        E, D, L = 0.0, {}, {}
        for host in hosts:
            e, D[host.h], L[host.h] = host.evaluate_safeguarded(trial, systems[host.h], D_new[host.h])
            E += e
        return E + _terms(problem, trial), D, L

    E = sum(host.start[0] for host in hosts) + _terms(problem, state)
    state_lins = {host.h: host.start[1] for host in hosts}
    initial = E
    lam = 1e-5
    it = 0
    for it in range(1, config.max_iterations + 1):
        H = np.zeros((M, M))
        g = np.zeros(M)
        systems = {host.h: host.linearize(depths[host.h], H, g, state_lins[host.h]) for host in hosts}
        _terms(problem, state, H, g)
        H = 0.5 * (H + H.T)
        diag = np.maximum(np.diag(H), 1e-12 * max(float(np.max(np.diag(H))), 1e-300))
        accepted = False
        for _ in range(10):
            dx = np.linalg.solve(H + lam * np.diag(diag), -g)
            trial = state.retract(dx)
            D = {h: system.back_substitute(dx) for h, system in systems.items()}
            E_new, D, L_new = cost(trial, D, systems)
            if E_new < E:
                accepted = True
                break
            lam *= 10.0
        if not accepted:
            break
        decrease = E - E_new
        state, depths, E, state_lins = trial, D, E_new, L_new
        lam = max(lam / 10.0, 1e-7)
        if on_iteration is not None:
            on_iteration(it, E)
        if decrease < config.relative_tolerance * max(E, 1e-300):
            break
    t_cov = time.perf_counter()
    covs = None
    if config.covariances:  # the undamped reduced system at the optimum (its residuals are kept: no new pass)
        with stage("covariances", absorb=True):
            H = np.zeros((M, M))
            g = np.zeros(M)
            for host in hosts:
                host.linearize(depths[host.h], H, g, state_lins[host.h])
            _terms(problem, state, H, g)
            covs = marginals_of_hessian(H, [kf.index for kf in keyframes])
    t_cov = time.perf_counter() - t_cov
    if problem.settings.keep_residuals and problem.settings.jacobian_budget is None:  # for the next pass there
        for host in hosts:
            host.remember(state, depths[host.h], state_lins[host.h])
    for k, kf in enumerate(keyframes):
        kf.pose = state.poses[k]
        kf.affine = np.asarray(state.affines[k], dtype=float).copy()
        if k in depths:
            kf.inverse_depth = depths[k].copy()
    variables = gtsam.Values()
    for key, v in state.vectors.items():
        variables.insert(key, np.asarray(v, dtype=float).copy())
    return WindowResult("handrolled", float(initial), float(E), it, time.perf_counter() - t0, problem.n_residuals(),
                        covs, t_cov if covs is not None else 0.0, vector_of(variables, rig_offset_key()),
                        vector_of(variables, calibration_key()), variables)
