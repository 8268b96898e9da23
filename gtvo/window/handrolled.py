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
from typing import TYPE_CHECKING, Callable, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.host_points import DepthSystem, HostPoints
from gtvo.core.keys import affine_key, calibration_key, is_pose_key, pose_key, rig_offset_key
from gtvo.core.camera import PinholeCamera
from gtvo.core.timing import stage, timed
from gtvo.window.covariance import marginals_of_hessian
from factors.params import DEFAULT_PHOTOMETRIC, PhotometricConfig
from gtvo.window.config import MarginalPrior, WindowConfig, WindowKeyframe, WindowResult
from gtvo.window.problem import (motion_factors, needs_rig_prior, rig_carried, rig_prior_mean_sigmas,
                                 visible_targets, wheel_carried, wheel_factors)

if TYPE_CHECKING:
    from gtvo.window.wheel import WheelCalibration

FloatArray = NDArray[np.float64]


# ----------------------------------------------------------------------------------------------
# hand-rolled solver: reduced camera system


class _WindowHost:
    """One host of the hand-rolled solver: its :class:`factors.host_points.HostPoints` (the same
    linearisation as :class:`factors.smart.HostPointsFactor`'s) and where its blocks sit in the
    window's state (8 entries per keyframe: pose, then affine; with ``rig`` the rig offset's 2
    entries after all keyframes').

    W is frozen at the window's starting state, where the host is built, as the smart factor
    does at its first evaluation, so both solvers minimise the same fixed cost.
    """

    @timed("window_build")  # the host's set-up (its first residuals: "linearisation")
    def __init__(self, camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                 h: int, targets: Sequence[int], config: WindowConfig, rig_offset: FloatArray | None = None,
                 photometric: PhotometricConfig = DEFAULT_PHOTOMETRIC) -> None:
        kh = keyframes[h]
        self.h, self.targets = h, list(targets)
        self.points = HostPoints(camera, kh.pixels, kh.image, [keyframes[t].image for t in self.targets],
                                 kh.variance, kh.prior_inverse_depth, sigma_intensity=photometric.sigma_intensity,
                                 huber_k=photometric.huber_k, pattern=photometric.pattern_array,
                                 depth_prior=kh.depth_prior,
                                 right_image=kh.right, baseline=baseline, lambda_stereo=config.lambda_stereo,
                                 stereo_affine=kh.stereo_affine, rig=rig_offset is not None)
        K = len(keyframes)
        self.rig_columns = np.arange(8 * K, 8 * K + 2) if self.points.rig else None
        # blocks [host pose, host affine, target pose, target affine]: 8 per keyframe
        self.columns = [np.r_[8 * h:8 * h + 8, 8 * t:8 * t + 8] for t in self.targets]
        poses, affines = self._local([k.pose for k in keyframes], [k.affine for k in keyframes])
        lins = self.points.residuals(poses, affines, kh.inverse_depth, offset=rig_offset)
        #: (E, lins) at the window's starting state (W frozen there): the initial cost and the first linearisation
        self.start = (float(self.points.point_costs(lins, kh.inverse_depth).sum()), lins)

    def _local(self, poses: Sequence, affines: Sequence) -> tuple[list, list]:
        """The host's and its targets' poses and affines, in :class:`HostPoints`' order."""
        idx = [self.h] + self.targets
        return [poses[i] for i in idx], [affines[i] for i in idx]

    def linearize(self, d: FloatArray, H: FloatArray, g: FloatArray, lins: list) -> DepthSystem:
        """Add this host's reduced Gauss-Newton terms (depths eliminated) to the window's ``H``, ``g``;
        ``lins``: the residuals at this state (:meth:`evaluate_safeguarded`'s or :attr:`start`'s)."""
        return self.points.linearize(lins, d, H, g, self.columns, self.rig_columns)

    def evaluate_safeguarded(self, poses, affines, system: DepthSystem, d_new: FloatArray,
                             offset: FloatArray | None = None) -> tuple[float, FloatArray, list]:
        """The cost at a trial state with the back-substituted inverse depths ``d_new``, except for
        points whose cost rose above their cost at ``system``'s linearisation point and that cost
        less at their depth there, which keep it (the safeguarded depth step, as the smart factor's):
        ``(cost, depths, linearisations)``."""
        P, A = self._local(poses, affines)
        c, d, lins = self.points.safeguard(P, A, system, d_new, self.points.residuals(P, A, d_new, offset=offset),
                                           offset)
        return float(c.sum()), d, lins


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


def _rig_prior_terms(config: WindowConfig, offset: FloatArray | None, active: bool, H=None, g=None,
                     hold_x: float | None = None, carried: bool = False) -> float:
    """The rig offset's prior (``active``: :func:`needs_rig_prior`; mean and sigmas of
    :func:`rig_prior_mean_sigmas`): cost, and (given H, g) its terms in the rig's entries (the last
    two of the state)."""
    if offset is None or not active:
        return 0.0
    mean, sigmas = rig_prior_mean_sigmas(config, hold_x, carried)
    e = (offset - mean) / sigmas
    if H is not None:
        H[-2:, -2:] += np.diag(1.0 / sigmas ** 2)
        g[-2:] += e / sigmas
    return 0.5 * float(e @ e)


def _state_values(keyframes, poses, affines, offset: FloatArray | None = None,
                  calibration: FloatArray | None = None) -> gtsam.Values:
    """A state of the hand-rolled solver as GTSAM ``Values`` (poses, affines, rig offset, wheel calibration)."""
    values = gtsam.Values()
    for k, kf in enumerate(keyframes):
        values.insert(pose_key(kf.index), poses[k])
        values.insert(affine_key(kf.index), affines[k])
    if offset is not None:
        values.insert(rig_offset_key(), np.asarray(offset, dtype=float))
    if calibration is not None:
        values.insert(calibration_key(), np.asarray(calibration, dtype=float))
    return values


def _state_columns(keyframes, offset: FloatArray | None = None, calibration: FloatArray | None = None
                   ) -> dict[int, int]:
    """Key -> its first column in the hand-rolled state (8 per keyframe, then the rig offset's 2,
    then the wheel calibration's)."""
    pos = {pose_key(kf.index): 8 * k for k, kf in enumerate(keyframes)}
    pos.update({affine_key(kf.index): 8 * k + 6 for k, kf in enumerate(keyframes)})
    pos[rig_offset_key()] = 8 * len(keyframes)
    if calibration is not None:
        pos[calibration_key()] = 8 * len(keyframes) + (0 if offset is None else 2)
    return pos


def _marginal_terms(marginal: MarginalPrior | None, keyframes, poses, affines, H=None, g=None,
                    offset: FloatArray | None = None, calibration: FloatArray | None = None) -> float:
    """The marginalisation prior's cost, and (given H, g) its terms (Jacobian of delta taken as I,
    as ``gtsam.LinearContainerFactor`` does); ``offset``: the rig offset (2 entries after the
    keyframes'); ``calibration``: the wheel calibration (the state's last entries)."""
    if marginal is None:
        return 0.0
    dl = marginal.delta(_state_values(keyframes, poses, affines, offset, calibration))
    if H is not None:
        pos = _state_columns(keyframes, offset, calibration)
        idx = np.concatenate([np.arange(pos[key], pos[key] + dim) for key, dim in zip(marginal.keys, marginal.dims)])
        H[np.ix_(idx, idx)] += marginal.H
        g[idx] += marginal.H @ dl - marginal.eta
    return float(0.5 * dl @ marginal.H @ dl - marginal.eta @ dl + 0.5 * marginal.f)


def _extra_terms(factors: gtsam.NonlinearFactorGraph | None, keyframes, poses, affines, H=None, g=None,
                 offset: FloatArray | None = None, calibration: FloatArray | None = None) -> float:
    """Native GTSAM factors on the keyframes' keys (the whole-log refinement's loop edges): their
    cost, and (given H, g) their Gauss-Newton terms from each factor's own linearisation
    (``JacobianFactor``: ``0.5 |A dx - b|^2``, GTSAM's right-perturbation tangent, as the poses' retraction here)."""
    if factors is None or factors.size() == 0:
        return 0.0
    values = _state_values(keyframes, poses, affines, offset, calibration)
    if H is not None:
        pos = _state_columns(keyframes, offset, calibration)
        for i in range(factors.size()):
            A, b = factors.at(i).linearize(values).jacobian()
            dims = [6 if is_pose_key(key) else values.atVector(key).shape[0] for key in factors.at(i).keys()]
            idx = np.concatenate([np.arange(pos[key], pos[key] + d) for key, d in zip(factors.at(i).keys(), dims)])
            H[np.ix_(idx, idx)] += A.T @ A
            g[idx] -= A.T @ b
    return float(factors.error(values))


def _wheel_terms(wheel: "WheelCalibration | None", factors: list, poses, calibration: FloatArray | None,
                 prior_on: bool, H=None, g=None) -> float:
    """The wheel factors (``factors``: :func:`wheel_factors` of the window) and, when ``prior_on``,
    the calibration's prior: cost, and (given H, g) their Gauss-Newton terms (the calibration's
    entries are the state's last ``wheel.size``)."""
    if wheel is None or calibration is None:
        return 0.0
    E = 0.0
    at = None if H is None else H.shape[0] - wheel.size
    for k, f in factors:
        e, J = f.whitened(poses[k], poses[k + 1], calibration)
        E += 0.5 * float(e @ e)
        if H is not None:
            cols = [np.arange(8 * k, 8 * k + 6), np.arange(8 * k + 8, 8 * k + 14), np.arange(at, at + wheel.size)]
            for a in range(3):
                g[cols[a]] += J[a].T @ e
                for b in range(3):
                    H[np.ix_(cols[a], cols[b])] += J[a].T @ J[b]
    if prior_on:
        E += wheel.prior_terms(calibration, H, g, 0 if at is None else at)
    return E


def window_cost(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                config: WindowConfig, marginal: MarginalPrior | None = None,
                targets: list[list[int]] | None = None, rig_offset: FloatArray | None = None,
                rig_hold_x: float | None = None, *, photometric: PhotometricConfig = DEFAULT_PHOTOMETRIC,
                wheel: "WheelCalibration | None" = None) -> float:
    """The window cost E at the keyframes' current state, computed the hand-rolled way (W at this
    state), with the ``photometric`` model (``wheel``: with the wheel factors at ``wheel.estimate``)."""
    targets = visible_targets(camera, keyframes, config) if targets is None else targets
    hosts = [_WindowHost(camera, baseline, keyframes, h, ts, config, rig_offset, photometric)
             for h, ts in enumerate(targets)]
    poses = [kf.pose for kf in keyframes]
    affines = [kf.affine for kf in keyframes]
    off = None if rig_offset is None else np.asarray(rig_offset, dtype=float).reshape(2)
    E = sum(host.start[0] for host in hosts)
    E += _prior_terms(keyframes, poses, affines, config, marginal is None)
    E += _rig_prior_terms(config, off, needs_rig_prior(off, marginal, rig_hold_x), hold_x=rig_hold_x,
                          carried=rig_carried(marginal))
    calib = None if wheel is None else wheel.estimate
    E += _wheel_terms(wheel, wheel_factors(keyframes, wheel), poses, calib, not wheel_carried(marginal))
    return E + _marginal_terms(marginal, keyframes, poses, affines, offset=off, calibration=calib)


def solve_handrolled(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                     config: WindowConfig, marginal: MarginalPrior | None = None,
                     targets: list[list[int]] | None = None, rig_offset: FloatArray | None = None,
                     rig_hold_x: float | None = None, *,
                     photometric: PhotometricConfig = DEFAULT_PHOTOMETRIC,
                     wheel: "WheelCalibration | None" = None,
                     extra_factors: gtsam.NonlinearFactorGraph | None = None,
                     on_iteration: Callable[[int, float], None] | None = None) -> WindowResult:
    """Levenberg-Marquardt on the reduced camera system (residuals of the ``photometric`` model);
    updates ``keyframes`` in place. ``extra_factors`` (native GTSAM factors on the keyframes' keys)
    and ``on_iteration`` as :func:`gtvo.window.solve_gtsam`'s.

    ``rig_offset``: the rig offset's current estimate when it is a variable (2 more state entries
    after the keyframes'; the result's ``rig_offset`` is the optimised one); ``rig_hold_x``: its
    ``delta_x`` held at this value (:func:`gtvo.window.problem.rig_prior_mean_sigmas`). ``wheel``:
    the wheel factors and the calibration (``wheel.size`` more entries, last; from
    ``wheel.estimate``, the result's ``wheel_calibration`` is the optimised one).

    Per iteration: every host's Gauss-Newton blocks over (poses, affines) ``x`` (8 per keyframe)
    and its inverse depths ``d`` (diagonal ``H_dd``), the Schur complement
    ``H_red = H_xx - sum_n H_xd H_xd^T / H_dd``, ``g_red = g_x - sum_n H_xd g_d / H_dd``, the
    damped step ``(H_red + lambda diag(H_red)) dx = -g_red`` and the back-substitution
    ``dd = -(g_d + H_xd^T dx) / H_dd``; the step is kept when the true cost decreases.
    """
    t0 = time.perf_counter()
    targets = visible_targets(camera, keyframes, config) if targets is None else targets
    off = None if rig_offset is None else np.asarray(rig_offset, dtype=float).reshape(2).copy()
    hosts = [_WindowHost(camera, baseline, keyframes, h, ts, config, off, photometric)
             for h, ts in enumerate(targets) if ts]
    K = len(keyframes)
    cal = None if wheel is None else np.asarray(wheel.estimate, dtype=float).copy()
    M = 8 * K + (0 if off is None else 2) + (0 if cal is None else cal.size)
    at_cal = M - (0 if cal is None else cal.size)
    wheel_fs = wheel_factors(keyframes, wheel)
    wheel_prior_on = not wheel_carried(marginal)
    rig_prior_on = needs_rig_prior(off, marginal, rig_hold_x)
    carried = rig_carried(marginal)
    with_gauge = marginal is None
    poses = [kf.pose for kf in keyframes]
    affines = [kf.affine.copy() for kf in keyframes]
    depths = {host.h: keyframes[host.h].inverse_depth.copy() for host in hosts}
    motion = motion_factors(keyframes, config)

    def cost(P, A, O, C, D_new, systems) -> tuple[float, dict[int, FloatArray], dict[int, list]]:
        E, D, L = 0.0, {}, {}
        for host in hosts:
            e, D[host.h], L[host.h] = host.evaluate_safeguarded(P, A, systems[host.h], D_new[host.h], O)
            E += e
        E += _prior_terms(keyframes, P, A, config, with_gauge, motion=motion)
        E += _rig_prior_terms(config, O, rig_prior_on, hold_x=rig_hold_x, carried=carried)
        E += _wheel_terms(wheel, wheel_fs, P, C, wheel_prior_on)
        E += _extra_terms(extra_factors, keyframes, P, A, offset=O, calibration=C)
        return E + _marginal_terms(marginal, keyframes, P, A, offset=O, calibration=C), D, L

    E = sum(host.start[0] for host in hosts) \
        + _prior_terms(keyframes, poses, affines, config, with_gauge, motion=motion) \
        + _rig_prior_terms(config, off, rig_prior_on, hold_x=rig_hold_x, carried=carried) \
        + _wheel_terms(wheel, wheel_fs, poses, cal, wheel_prior_on) \
        + _marginal_terms(marginal, keyframes, poses, affines, offset=off, calibration=cal) \
        + _extra_terms(extra_factors, keyframes, poses, affines, offset=off, calibration=cal)
    state_lins = {host.h: host.start[1] for host in hosts}
    initial = E
    lam = 1e-5
    it = 0
    for it in range(1, config.max_iterations + 1):
        H = np.zeros((M, M))
        g = np.zeros(M)
        systems = {host.h: host.linearize(depths[host.h], H, g, state_lins[host.h]) for host in hosts}
        _prior_terms(keyframes, poses, affines, config, with_gauge, H, g, motion)
        _rig_prior_terms(config, off, rig_prior_on, H, g, rig_hold_x, carried)
        _wheel_terms(wheel, wheel_fs, poses, cal, wheel_prior_on, H, g)
        _marginal_terms(marginal, keyframes, poses, affines, H, g, off, cal)
        _extra_terms(extra_factors, keyframes, poses, affines, H, g, off, cal)
        H = 0.5 * (H + H.T)
        diag = np.maximum(np.diag(H), 1e-12 * max(float(np.max(np.diag(H))), 1e-300))
        accepted = False
        for _ in range(10):
            dx = np.linalg.solve(H + lam * np.diag(diag), -g)
            P = [p.retract(dx[8 * k:8 * k + 6]) for k, p in enumerate(poses)]
            A = [a + dx[8 * k + 6:8 * k + 8] for k, a in enumerate(affines)]
            O = None if off is None else off + dx[8 * K:8 * K + 2]
            C = None if cal is None else cal + dx[at_cal:]
            D = {h: system.back_substitute(dx) for h, system in systems.items()}
            E_new, D, L_new = cost(P, A, O, C, D, systems)
            if E_new < E:
                accepted = True
                break
            lam *= 10.0
        if not accepted:
            break
        decrease = E - E_new
        poses, affines, off, cal, depths, E, state_lins = P, A, O, C, D, E_new, L_new
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
            _prior_terms(keyframes, poses, affines, config, with_gauge, H, g, motion)
            _rig_prior_terms(config, off, rig_prior_on, H, g, rig_hold_x, carried)
            _wheel_terms(wheel, wheel_fs, poses, cal, wheel_prior_on, H, g)
            _marginal_terms(marginal, keyframes, poses, affines, H, g, off, cal)
            _extra_terms(extra_factors, keyframes, poses, affines, H, g, off, cal)
            covs = marginals_of_hessian(H, [kf.index for kf in keyframes])
    t_cov = time.perf_counter() - t_cov
    for k, kf in enumerate(keyframes):
        kf.pose = poses[k]
        kf.affine = np.asarray(affines[k], dtype=float).copy()
        if k in depths:
            kf.inverse_depth = depths[k].copy()
    n_res = sum(len(keyframes[h]) * len(ts) for h, ts in enumerate(targets))
    return WindowResult("handrolled", float(initial), float(E), it, time.perf_counter() - t0, n_res,
                        covs, t_cov if covs is not None else 0.0, None if off is None else off.copy(),
                        None if cal is None else cal.copy())
