"""The window solved by a hand-rolled Levenberg-Marquardt on the reduced camera system.

Poses and affines are the unknowns of the reduced system; inverse depths are eliminated by the
Schur complement per host and recovered by back-substitution (docs/window.md). It minimises the
same cost as :mod:`gtvo.window.gtsam_solver`, and the tests compare the two.
"""

from __future__ import annotations

import time
from typing import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.photometric import (gauss_newton_sums, pattern_bearings, photometric_residuals, point_robust_terms,
                                 sample_host, stereo_residuals, variance_weight)
from factors.smart import keep_cheaper_depths
from gtvo.core.camera import PinholeCamera
from gtvo.window.config import MarginalPrior, WindowConfig, WindowKeyframe, WindowResult, affine_key, pose_key
from gtvo.window.problem import motion_factors, visible_targets

FloatArray = NDArray[np.float64]


# ----------------------------------------------------------------------------------------------
# hand-rolled solver: reduced camera system


class _HostTerms:
    """Frozen per-host data of the hand-rolled solver: host samples and the weights W.

    W is evaluated once, at the window's starting state, as :class:`HostPointsFactor` does at
    its first linearisation, so both solvers minimise the same fixed cost.
    """

    def __init__(self, camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                 h: int, targets: Sequence[int], config: WindowConfig) -> None:
        kh = keyframes[h]
        self.h, self.targets, self.camera, self.baseline, self.config = h, list(targets), camera, baseline, config
        self.host_I, self.host_valid = sample_host(kh.image, kh.pixels, config.pattern)
        self.bearings = pattern_bearings(camera, kh.pixels, config.pattern)  # fixed per host
        lins = self._lins(keyframes, kh.inverse_depth, [k.pose for k in keyframes], [k.affine for k in keyframes])
        self.W: list[FloatArray] = [variance_weight(lin.J_depth, kh.variance, config.sigma_intensity)
                                    for lin in lins[:-1]]
        self.W_stereo = None
        if lins[-1] is not None:
            self.W_stereo = config.lambda_stereo * variance_weight(lins[-1].J_depth, kh.variance,
                                                                   config.sigma_intensity)
        #: (E, lins) at the window's starting state: the initial cost and the first linearisation
        self.start = (self._cost_from(kh, kh.inverse_depth, lins), lins)

    def _lins(self, keyframes, d, poses, affines) -> list:
        """Linearisations (with Jacobians) into every target, then the stereo term (or None).

        LM evaluates the cost at a trial state and, when it accepts the step, linearises there:
        the Jacobians are computed in the cost pass (about a third of its time, the bilinear
        gathers being the rest) so that the accepted state is not evaluated twice.
        """
        kh = keyframes[self.h]
        out: list = [self._target(keyframes, t, d, poses, affines, jac=True) for t in self.targets]
        out.append(self._stereo(kh, d) if kh.right is not None else None)
        return out

    def _cost_from(self, kh: WindowKeyframe, d: FloatArray, lins: list) -> float:
        return float(self._point_costs_from(kh, d, lins).sum())

    def _point_costs_from(self, kh: WindowKeyframe, d: FloatArray, lins: list,
                          rows: NDArray[np.intp] | None = None) -> FloatArray:
        """Each point's cost: robust photometric and stereo losses and depth prior (``rows``: ``d``
        and ``lins`` hold only these points)."""
        sel = slice(None) if rows is None else rows
        c = np.zeros(d.shape[0] if rows is None else rows.size)
        for j, lin in enumerate(lins[:-1]):
            c += self._robust(self.W[j][sel], lin.residual)[1]
        if lins[-1] is not None:
            c += self._robust(self.W_stereo[sel], lins[-1].residual)[1]
        if kh.depth_prior:
            c += 0.5 * (d[sel] - kh.prior_inverse_depth[sel]) ** 2 / kh.variance[sel]
        return c

    def evaluate(self, keyframes, poses, affines, d) -> tuple[float, list]:
        """This host's cost at a state and the linearisations it was computed from."""
        lins = self._lins(keyframes, d, poses, affines)
        return self._cost_from(keyframes[self.h], d, lins), lins

    def evaluate_safeguarded(self, keyframes, poses, affines, d_new, d_old, c_old_lin
                             ) -> tuple[float, FloatArray, list]:
        """The cost at a trial state with the back-substituted inverse depths ``d_new``, except for
        points whose cost rose above their cost at the linearisation point (``c_old_lin``) and that
        cost less at their linearisation depth ``d_old``, which keep it (the safeguarded depth
        step of :class:`factors.smart.HostPointsFactor`): ``(cost, depths, linearisations)``."""
        kh = keyframes[self.h]
        lins = self._lins(keyframes, d_new, poses, affines)
        c = self._point_costs_from(kh, d_new, lins)
        d = d_new
        rows = np.flatnonzero(c > c_old_lin)
        if rows.size:
            lins_old = [self._target(keyframes, t, d_old, poses, affines, jac=True, rows=rows) for t in self.targets]
            lins_old.append(self._stereo(kh, d_old, rows) if kh.right is not None else None)
            c_old = self._point_costs_from(kh, d_old, lins_old, rows)
            d, c, lins = keep_cheaper_depths(d, c, lins, rows, d_old, c_old, lins_old)
        return float(c.sum()), d, lins

    def _target(self, keyframes, t, d, poses, affines, jac, rows=None):
        kh = keyframes[self.h]
        sel = slice(None) if rows is None else rows
        return photometric_residuals(self.camera, self.host_I[sel], self.host_valid[sel], kh.pixels[sel], d[sel],
                                     poses[self.h], poses[t], keyframes[t].image, affines[self.h], affines[t],
                                     self.config.pattern, jacobians=jac, host_jacobians=jac,
                                     bearings=self.bearings[sel])

    def _stereo(self, kh: WindowKeyframe, d: FloatArray, rows=None):
        sel = slice(None) if rows is None else rows
        return stereo_residuals(self.camera, self.baseline, self.host_I[sel], self.host_valid[sel], kh.pixels[sel],
                                d[sel], kh.right, (0.0, 0.0), kh.stereo_affine, self.config.pattern,
                                jacobians=False, bearings=self.bearings[sel])

    def _robust(self, W: FloatArray, r: FloatArray) -> tuple[FloatArray, FloatArray]:
        return point_robust_terms(W, r, self.config.huber_k)

    def cost(self, keyframes, poses, affines, d) -> float:
        return self.evaluate(keyframes, poses, affines, d)[0]

    def linearize(self, keyframes, poses, affines, d, H: FloatArray, g: FloatArray, lins: list | None = None):
        """Add this host's Gauss-Newton terms to the full ``H``, ``g`` (8 per keyframe); return
        ``(c (N,), H_pd (N, 8K), H_dd (N,), g_d (N,))`` with ``c`` each point's cost.
        ``lins``: :meth:`evaluate`'s at this state."""
        kh = keyframes[self.h]
        lins = self._lins(keyframes, d, poses, affines) if lins is None else lins
        n = d.shape[0]
        H_pd = np.zeros((n, H.shape[0]))
        H_dd = np.zeros(n)
        g_d = np.zeros(n)
        c = np.zeros(n)
        for j, t in enumerate(self.targets):
            lin = lins[j]
            w, loss = self._robust(self.W[j], lin.residual)
            c += loss
            # blocks [host pose, host affine, target pose, target affine]: 8 per keyframe
            H_t, g_t, H_pd_t, H_dd_t, g_d_t = gauss_newton_sums(lin, self.W[j] * w[:, None])
            cols = np.r_[8 * self.h:8 * self.h + 8, 8 * t:8 * t + 8]
            H[np.ix_(cols, cols)] += H_t
            g[cols] += g_t
            H_pd[:, cols] += H_pd_t
            H_dd += H_dd_t
            g_d += g_d_t
        if self.W_stereo is not None:
            st = lins[-1]
            w, loss = self._robust(self.W_stereo, st.residual)
            ww = self.W_stereo * w[:, None]
            H_dd += np.sum(ww * st.J_depth ** 2, axis=1)
            g_d += np.sum(ww * st.J_depth * st.residual, axis=1)
            c += loss
        if kh.depth_prior:
            H_dd += 1.0 / kh.variance
            g_d += (d - kh.prior_inverse_depth) / kh.variance
            c += 0.5 * (d - kh.prior_inverse_depth) ** 2 / kh.variance
        return c, H_pd, H_dd, g_d


def _prior_terms(keyframes, poses, affines, config, with_gauge, H=None, g=None, motion=None) -> float:
    """Affine priors, motion prior and gauge prior: cost, and (given H, g) their Gauss-Newton terms
    (``motion``: :func:`motion_factors` of these keyframes, if already built)."""
    E = 0.0
    for k, f in (motion_factors(keyframes, config) if motion is None else motion):
        e, J = f.whitened(poses[k], poses[k + 1], poses[k + 2])
        E += 0.5 * float(e @ e)
        if H is not None:
            for i in range(3):
                ri = slice(8 * (k + i), 8 * (k + i) + 6)
                g[ri] += J[i].T @ e
                for j in range(3):
                    H[ri, 8 * (k + j):8 * (k + j) + 6] += J[i].T @ J[j]
    s_aff = np.asarray(config.affine_sigma, dtype=float)
    for k, kf in enumerate(keyframes):
        e = (affines[k] - kf.affine_prior) / s_aff
        E += 0.5 * float(e @ e)
        if H is not None:
            idx = np.arange(8 * k + 6, 8 * k + 8)
            H[idx, idx] += 1.0 / s_aff ** 2
            g[idx] += e / s_aff
    if with_gauge:
        k0 = keyframes[0]
        s2 = config.gauge_sigma ** 2
        Jp = np.zeros((6, 6), order="F")
        e = np.asarray(k0.pose.localCoordinates(poses[0], None, Jp), dtype=float)
        ea = affines[0] - k0.affine
        E += 0.5 * float(e @ e + ea @ ea) / s2
        if H is not None:
            H[:6, :6] += Jp.T @ Jp / s2
            g[:6] += Jp.T @ e / s2
            H[6:8, 6:8] += np.eye(2) / s2
            g[6:8] += ea / s2
    return E


def _marginal_terms(marginal: MarginalPrior | None, keyframes, poses, affines, H=None, g=None) -> float:
    """The marginalisation prior's cost, and (given H, g) its terms (Jacobian of delta taken as I,
    as ``gtsam.LinearContainerFactor`` does)."""
    if marginal is None:
        return 0.0
    values = gtsam.Values()
    for k, kf in enumerate(keyframes):
        values.insert(pose_key(kf.index), poses[k])
        values.insert(affine_key(kf.index), affines[k])
    dl = marginal.delta(values)
    if H is not None:
        pos = {pose_key(kf.index): 8 * k for k, kf in enumerate(keyframes)}
        pos.update({affine_key(kf.index): 8 * k + 6 for k, kf in enumerate(keyframes)})
        idx = np.concatenate([np.arange(pos[key], pos[key] + dim) for key, dim in zip(marginal.keys, marginal.dims)])
        H[np.ix_(idx, idx)] += marginal.H
        g[idx] += marginal.H @ dl - marginal.eta
    return float(0.5 * dl @ marginal.H @ dl - marginal.eta @ dl + 0.5 * marginal.f)


def window_cost(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                config: WindowConfig, marginal: MarginalPrior | None = None,
                targets: list[list[int]] | None = None, terms: list[_HostTerms] | None = None) -> float:
    """The window cost E at the keyframes' current state, computed the hand-rolled way (W at this state)."""
    targets = visible_targets(camera, keyframes, config) if targets is None else targets
    if terms is None:
        terms = [_HostTerms(camera, baseline, keyframes, h, ts, config) for h, ts in enumerate(targets)]
    poses = [kf.pose for kf in keyframes]
    affines = [kf.affine for kf in keyframes]
    E = sum(t.cost(keyframes, poses, affines, keyframes[t.h].inverse_depth) for t in terms)
    E += _prior_terms(keyframes, poses, affines, config, marginal is None)
    return E + _marginal_terms(marginal, keyframes, poses, affines)


def solve_handrolled(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                     config: WindowConfig, marginal: MarginalPrior | None = None,
                     targets: list[list[int]] | None = None) -> WindowResult:
    """Levenberg-Marquardt on the reduced camera system; updates ``keyframes`` in place.

    Per iteration: every host's Gauss-Newton blocks over (poses, affines) ``x`` (8 per keyframe)
    and its inverse depths ``d`` (diagonal ``H_dd``), the Schur complement
    ``H_red = H_xx - sum_n H_xd H_xd^T / H_dd``, ``g_red = g_x - sum_n H_xd g_d / H_dd``, the
    damped step ``(H_red + lambda diag(H_red)) dx = -g_red`` and the back-substitution
    ``dd = -(g_d + H_xd^T dx) / H_dd``; the step is kept when the true cost decreases.
    """
    t0 = time.perf_counter()
    targets = visible_targets(camera, keyframes, config) if targets is None else targets
    terms = [_HostTerms(camera, baseline, keyframes, h, ts, config) for h, ts in enumerate(targets) if ts]
    K = len(keyframes)
    with_gauge = marginal is None
    poses = [kf.pose for kf in keyframes]
    affines = [kf.affine.copy() for kf in keyframes]
    depths = {t.h: keyframes[t.h].inverse_depth.copy() for t in terms}
    motion = motion_factors(keyframes, config)

    def cost(P, A, D_new, D_old, C_old) -> tuple[float, dict[int, FloatArray], dict[int, list]]:
        E, D, L = 0.0, {}, {}
        for t in terms:
            e, D[t.h], L[t.h] = t.evaluate_safeguarded(keyframes, P, A, D_new[t.h], D_old[t.h], C_old[t.h])
            E += e
        E += _prior_terms(keyframes, P, A, config, with_gauge, motion=motion)
        return E + _marginal_terms(marginal, keyframes, P, A), D, L

    E = sum(t.start[0] for t in terms) + _prior_terms(keyframes, poses, affines, config, with_gauge, motion=motion) \
        + _marginal_terms(marginal, keyframes, poses, affines)
    state_lins = {t.h: t.start[1] for t in terms}
    initial = E
    lam = 1e-5
    it = 0
    for it in range(1, config.max_iterations + 1):
        H = np.zeros((8 * K, 8 * K))
        g = np.zeros(8 * K)
        lins, point_costs = {}, {}
        for t in terms:
            point_costs[t.h], H_pd, H_dd, g_d = t.linearize(keyframes, poses, affines, depths[t.h], H, g,
                                                            state_lins[t.h])
            active = H_dd > 1e-12 * max(float(H_dd.max()), 1e-300)
            Hdd = np.where(active, H_dd, 1.0)
            L = H_pd[active] / Hdd[active, None]
            H -= L.T @ H_pd[active]
            g -= L.T @ g_d[active]
            lins[t.h] = (H_pd, Hdd, g_d, active)
        _prior_terms(keyframes, poses, affines, config, with_gauge, H, g, motion)
        _marginal_terms(marginal, keyframes, poses, affines, H, g)
        H = 0.5 * (H + H.T)
        diag = np.maximum(np.diag(H), 1e-12 * max(float(np.max(np.diag(H))), 1e-300))
        accepted = False
        for _ in range(10):
            dx = np.linalg.solve(H + lam * np.diag(diag), -g)
            P = [p.retract(dx[8 * k:8 * k + 6]) for k, p in enumerate(poses)]
            A = [a + dx[8 * k + 6:8 * k + 8] for k, a in enumerate(affines)]
            D = {}
            for h, (H_pd, Hdd, g_d, active) in lins.items():
                step = np.zeros_like(g_d)
                step[active] = -(g_d[active] + H_pd[active] @ dx) / Hdd[active]
                D[h] = np.maximum(depths[h] + step, 0.1 * depths[h])
            E_new, D, L_new = cost(P, A, D, depths, point_costs)
            if E_new < E:
                accepted = True
                break
            lam *= 10.0
        if not accepted:
            break
        decrease = E - E_new
        poses, affines, depths, E, state_lins = P, A, D, E_new, L_new
        lam = max(lam / 10.0, 1e-7)
        if decrease < config.relative_tolerance * max(E, 1e-300):
            break
    for k, kf in enumerate(keyframes):
        kf.pose = poses[k]
        kf.affine = np.asarray(affines[k], dtype=float).copy()
        if k in depths:
            kf.inverse_depth = depths[k].copy()
    n_res = sum(len(keyframes[h]) * len(ts) for h, ts in enumerate(targets))
    return WindowResult("handrolled", float(initial), float(E), it, time.perf_counter() - t0, n_res)
