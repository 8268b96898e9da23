"""Building the window's problem: its values, which keyframes see which host's points, and its factors.

The factors of the cost of docs/window.md: one :class:`factors.smart.HostPointsFactor` per host, the
weak affine priors, the constant-velocity priors, the gauge prior and the marginalisation prior
(with wheel odometry also the wheel factors and the calibration's prior: :mod:`gtvo.window.wheel`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.keys import affine_key, calibration_key, pose_key, rig_offset_key
from factors.params import DEFAULT_PHOTOMETRIC, PhotometricConfig
from factors.smart import HostPointsFactor, JacobianBudget
from factors.smoothness import ConstantVelocityFactor
from factors.stacked import stacked
from gtvo.core.camera import MIN_DEPTH, PinholeCamera
from gtvo.core.timing import timed
from gtvo.errors import InputError
from gtvo.window.config import MarginalPrior, WindowConfig, WindowKeyframe

if TYPE_CHECKING:
    from factors.wheel_odometry import WheelOdometryFactor
    from gtvo.window.wheel import WheelCalibration

FloatArray = NDArray[np.float64]


# ----------------------------------------------------------------------------------------------
# the problem shared by both solvers


def key_ordering(keys: Sequence[int]) -> gtsam.Ordering:
    o = gtsam.Ordering()
    for k in keys:
        o.push_back(k)
    return o


def window_values(keyframes: Sequence[WindowKeyframe], rig_offset: FloatArray | None = None,
                  wheel: "WheelCalibration | None" = None) -> gtsam.Values:
    """The keyframes' poses and affines (and the rig offset, if estimated, and the wheel
    calibration, with wheel odometry) as GTSAM ``Values``."""
    v = gtsam.Values()
    for kf in keyframes:
        v.insert(pose_key(kf.index), kf.pose)
        v.insert(affine_key(kf.index), kf.affine)
    if rig_offset is not None:
        v.insert(rig_offset_key(), np.asarray(rig_offset, dtype=float).reshape(2))
    if wheel is not None:
        v.insert(calibration_key(), np.asarray(wheel.estimate, dtype=float).copy())
    return v


def wheel_carried(marginal: MarginalPrior | None) -> bool:
    """Whether the marginalisation prior carries the wheel calibration (it then holds its prior)."""
    return marginal is not None and calibration_key() in marginal.keys


def wheel_factors(keyframes: Sequence[WindowKeyframe], wheel: "WheelCalibration | None"
                  ) -> list[tuple[int, "WheelOdometryFactor"]]:
    """The wheel factors ``(k, factor)`` between keyframes ``k, k+1`` (positions) the wheel log
    covers (none without wheel odometry)."""
    return [] if wheel is None else wheel.factors(keyframes, lambda kf: pose_key(kf.index))


def needs_rig_prior(rig_offset: FloatArray | None, marginal: MarginalPrior | None,
                    hold_x: float | None = None) -> bool:
    """Whether the window's graph gets the rig offset's prior: the rig is estimated and no
    marginalisation prior carries it yet (the zero-mean prior is set once, like the gauge prior),
    or ``delta_x`` is held (``hold_x``: the hold is in every window while it lasts)."""
    return rig_offset is not None and (hold_x is not None or not rig_carried(marginal))


def rig_carried(marginal: MarginalPrior | None) -> bool:
    """Whether the marginalisation prior carries the rig offset (it then holds its zero-mean prior)."""
    return marginal is not None and rig_offset_key() in marginal.keys


#: sigma (px) of the prior that holds ``delta_x`` at its start value while the window is not full
RIG_HOLD_SIGMA = 1e-3


def rig_prior_mean_sigmas(config: WindowConfig, hold_x: float | None, carried: bool = False
                          ) -> tuple[FloatArray, FloatArray]:
    """Mean and sigmas of the rig offset's prior: zero mean, ``config.rig_offset_sigma`` px on each
    axis; with ``hold_x`` (a value) ``delta_x`` is held there (:data:`RIG_HOLD_SIGMA`): the window
    is not full yet, or its estimate was not significant (docs/window.md, "Rig calibration").
    ``carried``: the marginalisation prior already carries the zero-mean prior, so only the hold
    remains (``delta_y``'s sigma infinite)."""
    mean = np.zeros(2)
    sigmas = np.full(2, float(config.rig_offset_sigma))
    if carried:
        sigmas[1] = np.inf
    if hold_x is not None:
        mean[0], sigmas[0] = float(hold_x), RIG_HOLD_SIGMA
    return mean, sigmas


def rig_prior(config: WindowConfig, hold_x: float | None = None, carried: bool = False) -> gtsam.PriorFactorVector:
    """The rig offset's prior (:func:`rig_prior_mean_sigmas`) as a GTSAM factor."""
    mean, sigmas = rig_prior_mean_sigmas(config, hold_x, carried)
    return gtsam.PriorFactorVector(rig_offset_key(), mean, gtsam.noiseModel.Diagonal.Precisions(sigmas ** -2.0))


@timed("window_build")
def visible_targets(camera: PinholeCamera, keyframes: Sequence[WindowKeyframe], config: WindowConfig,
                    hosts: Sequence[int] | None = None, candidates: Sequence[Sequence[int]] | None = None,
                    max_targets: int | None = None) -> list[list[int]]:
    """For each host (position in ``keyframes``), the positions of the keyframes that see its points.

    A point counts as seen when it projects in front of the target and inside its image with a
    2-pixel border (:func:`seen_in`); a target needs ``min_visible_points`` and
    ``min_visible_fraction`` of them. ``hosts``: only these hosts' lists (in this order; default
    all). ``candidates``: per host (in the order of ``hosts``), the only positions tried (default
    every other keyframe: the window's); ``max_targets``: keep at most this many targets per host,
    those that see most of its points (ties: the nearer in order), listed in increasing position
    (default all: the window's).
    """
    out: list[list[int]] = []
    for i, h in enumerate(range(len(keyframes)) if hosts is None else hosts):
        if not 0 <= h < len(keyframes):
            raise InputError(f"visible_targets: host position {h} is not in a window of {len(keyframes)} keyframes")
        kh = keyframes[h]
        Xw = host_points_world(camera, kh)  # once per host, not per host and target
        seen: list[tuple[int, int]] = []  # (points seen, position)
        for t in range(len(keyframes)) if candidates is None else candidates[i]:
            if t == h:
                continue
            n = int(np.count_nonzero(seen_in(camera, kh, keyframes[t], Xw)))
            if n >= config.min_visible_points and n >= config.min_visible_fraction * len(kh):
                seen.append((n, t))
        if max_targets is not None and len(seen) > max_targets:
            seen = sorted(seen, key=lambda nt: (-nt[0], abs(nt[1] - h), nt[1]))[:max_targets]
        out.append(sorted(t for _, t in seen))
    return out


def host_points_world(camera: PinholeCamera, host: WindowKeyframe) -> FloatArray:
    """The host's points in the world frame (N, 3), at their current inverse depths and host pose."""
    X = camera.backproject_inverse_depth(host.pixels, host.inverse_depth)
    Th = host.pose.matrix()
    return X @ Th[:3, :3].T + Th[:3, 3]


def seen_in(camera: PinholeCamera, host: WindowKeyframe, target: WindowKeyframe,
            points_world: FloatArray | None = None) -> NDArray[np.bool_]:
    """Per point of ``host``: does it project in front of ``target`` and inside its image (2-px border)?
    ``points_world``: :func:`host_points_world` of ``host`` when the caller has it."""
    Xw = host_points_world(camera, host) if points_world is None else points_world
    Tt = target.pose.inverse().matrix()
    Xt = Xw @ Tt[:3, :3].T + Tt[:3, 3]
    front = Xt[:, 2] > MIN_DEPTH
    z = np.where(front, Xt[:, 2], 1.0)
    u = camera.fx * Xt[:, 0] / z + camera.cx
    v = camera.fy * Xt[:, 1] / z + camera.cy
    return front & (u >= 2) & (u <= camera.width - 3) & (v >= 2) & (v <= camera.height - 3)


def observation_counts(camera: PinholeCamera, keyframes: Sequence[WindowKeyframe], targets: list[list[int]]
                       ) -> list[NDArray[np.int64]]:
    """For each host, per point: in how many of its ``targets`` (the keyframes its factor compares it
    with, :func:`visible_targets`) the point is seen (:func:`seen_in`). The host itself is not counted."""
    out: list[NDArray[np.int64]] = []
    for h, kh in enumerate(keyframes):
        n = np.zeros(len(kh), dtype=np.int64)
        Xw = host_points_world(camera, kh) if targets[h] else None
        for t in targets[h]:
            n += seen_in(camera, kh, keyframes[t], Xw)
        out.append(n)
    return out


def gauge_noise(config: WindowConfig, dim: int) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Isotropic.Sigma(dim, config.gauge_sigma)


def motion_factors(keyframes: Sequence[WindowKeyframe], config: WindowConfig
                   ) -> list[tuple[int, ConstantVelocityFactor]]:
    """The motion-smoothness prior: ``(k, factor)`` for every three consecutive keyframes
    ``k, k+1, k+2`` (positions) with increasing timestamps (none when ``acceleration_sigma`` is None)."""
    if config.acceleration_sigma is None:
        return []
    out = []
    for k in range(len(keyframes) - 2):
        a, b, c = keyframes[k], keyframes[k + 1], keyframes[k + 2]
        if a.timestamp is None or b.timestamp is None or c.timestamp is None:
            continue
        dt_prev, dt_next = b.timestamp - a.timestamp, c.timestamp - b.timestamp
        if dt_prev > 0 and dt_next > 0:
            out.append((k, ConstantVelocityFactor(pose_key(a.index), pose_key(b.index), pose_key(c.index),
                                                  dt_prev, dt_next, *config.acceleration_sigma)))
    return out


def prior_factors(keyframes: Sequence[WindowKeyframe], config: WindowConfig, with_gauge: bool
                  ) -> gtsam.NonlinearFactorGraph:
    """Affine priors of every keyframe, and (``with_gauge``) the gauge prior on the oldest."""
    g = gtsam.NonlinearFactorGraph()
    aff_noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(config.affine_sigma, dtype=float))
    for kf in keyframes:
        g.add(gtsam.PriorFactorVector(affine_key(kf.index), np.asarray(kf.affine_prior, dtype=float), aff_noise))
    if with_gauge and keyframes:
        k0 = keyframes[0]
        g.add(gtsam.PriorFactorPose3(pose_key(k0.index), k0.pose, gauge_noise(config, 6)))
        g.add(gtsam.PriorFactorVector(affine_key(k0.index), k0.affine.copy(), gauge_noise(config, 2)))
    return g


@timed("window_build")
def host_factor(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe], h: int,
                targets: Sequence[int], config: WindowConfig, rig: bool = False, *,
                photometric: PhotometricConfig = DEFAULT_PHOTOMETRIC,
                jacobian_budget: JacobianBudget | None = None) -> HostPointsFactor:
    """The :class:`HostPointsFactor` of host ``keyframes[h]`` observed in ``targets`` (positions),
    weighed by the ``photometric`` model; ``rig``: its stereo term has the rig offset variable
    (:func:`gtvo.core.keys.rig_offset_key`); ``jacobian_budget``: the factor's (shared) budget of
    kept Jacobians (:class:`factors.smart.JacobianBudget`; None: no limit, the window's)."""
    kh = keyframes[h]
    return HostPointsFactor(
        pose_key(kh.index), [pose_key(keyframes[t].index) for t in targets], camera, kh.pixels,
        kh.inverse_depth, kh.image, [keyframes[t].image for t in targets], kh.variance,
        sigma_intensity=photometric.sigma_intensity, huber_k=photometric.huber_k, affine_host_key=affine_key(kh.index),
        affine_target_keys=[affine_key(keyframes[t].index) for t in targets], depth_prior=kh.depth_prior,
        pattern=photometric.pattern_array, right_image=kh.right, baseline=baseline if kh.right is not None else None,
        lambda_stereo=config.lambda_stereo, stereo_affine=kh.stereo_affine,
        prior_inverse_depth=kh.prior_inverse_depth,
        rig_key=rig_offset_key() if rig and kh.right is not None else None, jacobian_budget=jacobian_budget)


@timed("window_build")
def build_graph(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                config: WindowConfig, marginal: MarginalPrior | None,
                targets: list[list[int]] | None = None, rig_offset: FloatArray | None = None,
                rig_hold_x: float | None = None, *, photometric: PhotometricConfig = DEFAULT_PHOTOMETRIC,
                wheel: "WheelCalibration | None" = None, jacobian_budget: JacobianBudget | None = None,
                stack: int = 1) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, dict[int, HostPointsFactor]]:
    """The window's factor graph: one smart factor per host with targets, priors, motion prior,
    marginal prior; with ``rig_offset`` (its current estimate) the rig offset is a variable of
    every stereo host factor, with :func:`rig_prior` until the marginal prior carries it
    (``rig_hold_x``: its ``delta_x`` held at that value); with ``wheel`` the wheel factors and the
    calibration variable, with its prior until the marginal prior carries it; ``jacobian_budget``:
    shared by the host factors (:func:`host_factor`; the whole-log refinement's); ``stack``: the motion
    priors and the host factors in runs of this many, each run one GTSAM factor
    (:func:`factors.stacked.stacked`: fewer copies of the Values in GTSAM's optimisers).

    Returns ``(graph, values, host_factors)`` with ``host_factors[position] = factor``.
    """
    targets = visible_targets(camera, keyframes, config) if targets is None else targets
    graph = prior_factors(keyframes, config, with_gauge=marginal is None)
    for f in stacked([f for _, f in motion_factors(keyframes, config)], stack):
        graph.add(f)
    hosts: dict[int, HostPointsFactor] = {}
    for h, ts in enumerate(targets):
        if ts:
            hosts[h] = host_factor(camera, baseline, keyframes, h, ts, config, rig=rig_offset is not None,
                                   photometric=photometric, jacobian_budget=jacobian_budget)
    for f in stacked(list(hosts.values()), stack):
        graph.add(f)
    if marginal is not None:
        for f in marginal.nonlinear_factors():
            graph.add(f)
    if needs_rig_prior(rig_offset, marginal, rig_hold_x):
        graph.add(rig_prior(config, rig_hold_x, rig_carried(marginal)))
    if wheel is not None:
        for _, f in wheel_factors(keyframes, wheel):
            graph.add(f)
        if not wheel_carried(marginal):
            graph.add(wheel.prior_factor())
    return graph, window_values(keyframes, rig_offset, wheel), hosts
