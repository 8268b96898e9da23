"""Building the window's problem: its values, which keyframes see which host's points, and its factors.

The factors of the cost of docs/window.md: one :class:`factors.smart.HostPointsFactor` per host, the
weak affine priors, the constant-velocity priors, the gauge prior and the marginalisation prior
(with wheel odometry also the wheel factors and the calibration's prior: :mod:`gtvo.window.wheel`).
:class:`WindowProblem` carries them, with the keyframes and the settings, to both solvers, the
marginalisation and the refinement: every factor but the host factors in one GTSAM graph.
"""

from __future__ import annotations

import dataclasses
import weakref
from dataclasses import dataclass, field
from typing import Callable, Protocol, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.keys import affine_key, pose_key, rig_offset_key
from factors.params import DEFAULT_PHOTOMETRIC, PhotometricConfig
from factors.host_points import HostSamples
from factors.smart import HostPointsFactor, JacobianBudget
from factors.smoothness import ConstantVelocityFactor
from factors.stacked import stacked
from gtvo.core.camera import MIN_DEPTH, PinholeCamera
from gtvo.core.timing import timed
from gtvo.errors import InputError
from gtvo.window import residual_memo
from gtvo.window.config import MarginalPrior, WindowConfig, WindowKeyframe, WindowState

FloatArray = NDArray[np.float64]


# ----------------------------------------------------------------------------------------------
# the problem shared by both solvers


def vector_of(values: gtsam.Values, key: int) -> FloatArray | None:
    """A copy of the vector at ``key`` in ``values``, None when it has none."""
    return np.asarray(values.atVector(key), dtype=float).copy() if values.exists(key) else None


def key_ordering(keys: Sequence[int]) -> gtsam.Ordering:
    o = gtsam.Ordering()
    for k in keys:
        o.push_back(k)
    return o


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


@dataclass(frozen=True)
class TargetChoice:
    """Which targets :func:`visible_targets` tries and keeps.

    Attributes:
        hosts: only these hosts' lists (positions, in this order); None: every host.
        candidates: per host (in the order of ``hosts``), the only positions tried; None: every
            other keyframe (the window's).
        max_targets: keep at most this many targets per host, those that see most of its points
            (ties: the nearer in order), listed in increasing position; None: all (the window's).
    """

    hosts: Sequence[int] | None = None
    candidates: Sequence[Sequence[int]] | None = None
    max_targets: int | None = None


@timed("window_build")
def visible_targets(camera: PinholeCamera, keyframes: Sequence[WindowKeyframe], config: WindowConfig,
                    choice: "TargetChoice | None" = None) -> list[list[int]]:
    """For each host (position in ``keyframes``), the positions of the keyframes that see its points.

    A point counts as seen when it projects in front of the target and inside its image with a
    2-pixel border (:func:`seen_in`); a target needs ``min_visible_points`` and
    ``min_visible_fraction`` of them. ``choice``: which hosts, which candidates and how many
    targets (:class:`TargetChoice`; default: every host, every other keyframe, all of them: the window's).
    """
    choice = choice or TargetChoice()
    hosts, candidates, max_targets = choice.hosts, choice.candidates, choice.max_targets
    out: list[list[int]] = []
    inverse: FloatArray | None = None
    for i, h in enumerate(range(len(keyframes)) if hosts is None else hosts):
        if not 0 <= h < len(keyframes):
            raise InputError(f"visible_targets: host position {h} is not in a window of {len(keyframes)} keyframes")
        kh = keyframes[h]
        others = [t for t in (range(len(keyframes)) if candidates is None else candidates[i]) if t != h]
        if not others:
            out.append([])
            continue
        if inverse is None:  # each keyframe's T_cam_world once per call, not per host and target
            inverse = np.stack([kf.pose.inverse().matrix() for kf in keyframes])
        # all candidates of the host at once: host_points_world once per host
        counts = np.count_nonzero(seen_in_targets(camera, host_points_world(camera, kh), inverse[others]), axis=1)
        seen: list[tuple[int, int]] = [(int(n), t) for n, t in zip(counts, others)  # (points seen, position)
                                       if n >= config.min_visible_points and n >= config.min_visible_fraction * len(kh)]
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


def seen_in_targets(camera: PinholeCamera, points_world: FloatArray, T_cam_world: FloatArray) -> NDArray[np.bool_]:
    """:func:`seen_in` of one host's points (``points_world`` (N, 3)) in several targets at once, given
    as their ``T_cam_world`` (K, 4, 4): (K, N), the same values as K calls (the same products)."""
    Xt = points_world @ T_cam_world[:, :3, :3].transpose(0, 2, 1) + T_cam_world[:, None, :3, 3]
    front = Xt[..., 2] > MIN_DEPTH
    z = np.where(front, Xt[..., 2], 1.0)
    u = camera.fx * Xt[..., 0] / z + camera.cx
    v = camera.fy * Xt[..., 1] / z + camera.cy
    return front & (u >= 2) & (u <= camera.width - 3) & (v >= 2) & (v <= camera.height - 3)


def observation_counts(camera: PinholeCamera, keyframes: Sequence[WindowKeyframe], targets: list[list[int]]
                       ) -> list[NDArray[np.int64]]:
    """For each host, per point: in how many of its ``targets`` (the keyframes its factor compares it
    with, :func:`visible_targets`) the point is seen (:func:`seen_in`). The host itself is not counted."""
    out: list[NDArray[np.int64]] = []
    inverse = np.stack([kf.pose.inverse().matrix() for kf in keyframes]) if any(targets) else None
    for h, kh in enumerate(keyframes):
        if not targets[h]:
            out.append(np.zeros(len(kh), dtype=np.int64))
            continue
        seen = seen_in_targets(camera, host_points_world(camera, kh), inverse[list(targets[h])])
        out.append(np.count_nonzero(seen, axis=0).astype(np.int64))
    return out


def gauge_noise(config: WindowConfig, dim: int) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Isotropic.Sigma(dim, config.gauge_sigma)


#: the motion prior's factors made so far, by their keys, time steps and sigmas (a factor is a pure
#: function of the poses: the window's problems, several per keyframe, share them)
_MOTION: dict[tuple, ConstantVelocityFactor] = {}
#: :data:`_MOTION` is emptied beyond this many factors (a window has a few)
_MAX_MOTION = 64


def motion_factors(keyframes: Sequence[WindowKeyframe], config: WindowConfig
                   ) -> list[tuple[int, ConstantVelocityFactor]]:
    """The motion-smoothness prior: ``(k, factor)`` for every three consecutive keyframes
    ``k, k+1, k+2`` (positions) with increasing timestamps (none when ``acceleration_sigma`` is None).
    A factor with the same keys, time steps and sigmas as one made before is that one (it holds no
    state: the same errors and Jacobians)."""
    if config.acceleration_sigma is None:
        return []
    out = []
    for k in range(len(keyframes) - 2):
        a, b, c = keyframes[k], keyframes[k + 1], keyframes[k + 2]
        if a.timestamp is None or b.timestamp is None or c.timestamp is None:
            continue
        dt_prev, dt_next = b.timestamp - a.timestamp, c.timestamp - b.timestamp
        if dt_prev > 0 and dt_next > 0:
            keys = (pose_key(a.index), pose_key(b.index), pose_key(c.index))
            sigmas = tuple(np.asarray(config.acceleration_sigma, dtype=float).ravel())
            made = (keys, float(dt_prev), float(dt_next), sigmas)
            factor = _MOTION.get(made)
            if factor is None:
                if len(_MOTION) >= _MAX_MOTION:
                    _MOTION.clear()
                factor = _MOTION[made] = ConstantVelocityFactor(*keys, dt_prev, dt_next, *config.acceleration_sigma)
            out.append((k, factor))
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


# ----------------------------------------------------------------------------------------------
# the window problem: one value for both solvers, the marginalisation and the refinement


@dataclass(frozen=True)
class WindowMembers:
    """The keyframes of a window problem and what their points are compared with.

    Attributes:
        camera: the left camera's intrinsics (all keyframes share them).
        baseline: the stereo baseline (m), None for RGB-D input.
        keyframes: the members, oldest first; the solvers update their poses, affines and inverse
            depths in place.
        targets: per host (position), the positions of the keyframes its points are compared with
            (:func:`visible_targets`); None: the window's rule at the keyframes' current state.
    """

    camera: PinholeCamera
    baseline: float | None
    keyframes: Sequence[WindowKeyframe]
    targets: list[list[int]] | None = None


@dataclass(frozen=True)
class RigVariable:
    """The stereo rig's offset ``(delta_x, delta_y)`` (px) as a variable of the problem.

    Attributes:
        offset: its current estimate (the start of the solve).
        hold_x: ``delta_x`` held at this value (:func:`rig_prior`); None: free.
    """

    offset: FloatArray
    hold_x: float | None = None


@dataclass(frozen=True)
class WindowSettings:
    """How a window problem is built and solved: a parameter object, as GTSAM's
    ``LevenbergMarquardtParams`` (its ``iterationHook`` is :attr:`on_iteration` here).

    Attributes:
        config: the window's settings (weights, priors, motion prior, LM iterations and tolerance).
        photometric: the photometric model of the host factors' residuals.
        jacobian_budget: the host factors' shared budget of kept Jacobians (the whole-log
            refinement's memory bound, :class:`factors.smart.JacobianBudget`; None: no limit, the window's).
        stack: the Python factors in runs of this many per GTSAM factor
            (:func:`factors.stacked.stacked`: fewer copies of the Values in GTSAM's optimisers).
        on_iteration: called with ``(iteration, cost)`` after every LM iteration (a progress bar,
            a Ctrl-C check); GTSAM's optimiser then runs iteration by iteration.
        keep_residuals: the solvers keep each host's residuals at the optimum for the next pass
            there (:mod:`gtvo.window.residual_memo`: the sliding window's next solve, its
            marginalisation, its rig test); False: nothing kept (a one-off solve, the refinement).
            Either way a host factor starts from residuals kept at its state.
    """

    config: WindowConfig = field(default_factory=WindowConfig)
    photometric: PhotometricConfig = DEFAULT_PHOTOMETRIC
    jacobian_budget: JacobianBudget | None = None
    stack: int = 1
    on_iteration: Callable[[int, float], None] | None = None
    keep_residuals: bool = False


class WindowSensor(Protocol):
    """A source of variables and factors beyond the camera's, added to every window problem (the
    wheel odometry, :class:`gtvo.window.wheel.WheelCalibration`; docs/extending.md)."""

    def add_to(self, problem: "WindowProblem") -> None:
        """Insert this sensor's variables into ``problem.variables`` (per keyframe: a kind in
        ``problem.keyframe_kinds``) and its factors into ``problem.factors``; a prior set once goes
        in only while ``problem.marginal`` does not carry its variable."""


class SolvableWindow(WindowState, Protocol):
    """What a back end sees of the window it serves: its state and its problem
    (:class:`gtvo.window.SlidingWindowOptimizer`)."""

    def problem(self, targets: list[list[int]] | None = None, rig: "RigVariable | None" = None) -> "WindowProblem":
        """The window's problem at its current state (``targets``: the hosts' targets, None: chosen
        at the first use; ``rig``: the rig offset as a variable, None: none)."""

    def solved_rig(self) -> "RigVariable | None":
        """The rig offset as a variable of the window's problem, not held (None: none)."""


@dataclass(frozen=True)
class WindowProblem:
    """Everything a window solve needs, in one value (docs/window.md, "The window problem").

    The host factors (one :class:`factors.smart.HostPointsFactor` per host with targets, the
    photometric and stereo terms) are built by each solver from :attr:`members` (their fast path);
    every other factor lives in :attr:`factors`, one ``gtsam.NonlinearFactorGraph`` that both
    solvers consume: the affine priors, the gauge prior (no marginalisation prior yet), the motion
    prior, the rig offset's prior, the sensors' factors (the wheel factors and the calibration's
    prior), and whatever a caller adds (the refinement's loop edges, a new factor:
    docs/extending.md). The marginalisation prior :attr:`marginal` is a quadratic kept apart (both
    solvers add it as it is).

    Build it with :meth:`build`; add a factor with ``problem.factors.add(factor)`` and a new
    variable with ``problem.variables.insert(key, value)`` (a vector).

    Attributes:
        members: the keyframes, their camera and their targets (:class:`WindowMembers`).
        settings: how it is solved (:class:`WindowSettings`).
        marginal: the marginalisation prior (None: the gauge prior holds the oldest keyframe).
        rig: the rig offset as a variable (None: the rectified model).
        sensors: the sensors whose variables and factors the problem has (:class:`WindowSensor`:
            the wheel odometry, whose calibration variable starts at its estimate; a solve does
            not change them: the result carries the optimised variables).
        factors: the problem's non-host factors (see above).
        variables: the values of the problem's variables beyond the keyframes' poses and affines:
            the rig offset, the wheel calibration, then any a caller inserts (vectors), in this order.
        keyframe_kinds: the symbol characters of the variable kinds each keyframe has beyond its
            pose and affine (``gtsam.symbol(kind, keyframe.index)`` in :attr:`variables`, e.g. a
            velocity): the marginalisation eliminates them with their keyframe.
        host_position: in GTSAM's graph the host factors and the marginalisation prior come after
            this many of :attr:`factors` (the affine, gauge and motion priors): the order of the
            sums, and so every bit of a result, is as it always was.
        gauge_factors: the positions in :attr:`factors` of the gauge prior (empty with a
            marginalisation prior); the marginalisation adds them where the previous prior goes.
    """

    members: WindowMembers
    settings: WindowSettings
    marginal: MarginalPrior | None
    rig: RigVariable | None
    sensors: tuple[WindowSensor, ...]
    factors: gtsam.NonlinearFactorGraph
    variables: gtsam.Values
    keyframe_kinds: list[str]
    host_position: int
    gauge_factors: range

    @classmethod
    @timed("window_build")
    def build(cls, members: WindowMembers, settings: WindowSettings | None = None,
              marginal: MarginalPrior | None = None, rig: RigVariable | None = None,
              sensors: Sequence[WindowSensor | None] = ()) -> "WindowProblem":
        """The problem of ``members`` (targets chosen by :func:`visible_targets` when None) with its
        non-host factors: affine priors, the gauge prior without ``marginal``, the motion prior
        (in runs of ``settings.stack``), the rig offset's prior (:func:`needs_rig_prior`), then
        each sensor's variables and factors (:meth:`WindowSensor.add_to`; None entries are skipped:
        the wheel factors and, until ``marginal`` carries it, the calibration's prior)."""
        settings = settings or WindowSettings()
        config = settings.config
        keyframes = members.keyframes
        graph = prior_factors(keyframes, config, with_gauge=marginal is None)
        gauge = range(len(keyframes), graph.size())  # after the affine priors
        for f in stacked([f for _, f in motion_factors(keyframes, config)], settings.stack):
            graph.add(f)
        host_position = graph.size()
        offset = None if rig is None else rig.offset
        hold = None if rig is None else rig.hold_x
        if needs_rig_prior(offset, marginal, hold):
            graph.add(rig_prior(config, hold, rig_carried(marginal)))
        variables = gtsam.Values()
        if offset is not None:
            variables.insert(rig_offset_key(), np.asarray(offset, dtype=float).reshape(2).copy())
        problem = cls(members, settings, marginal, rig, tuple(s for s in sensors if s is not None), graph, variables,
                      [], host_position, gauge)
        for sensor in problem.sensors:
            sensor.add_to(problem)
        return problem

    @property
    def camera(self) -> PinholeCamera:
        """The left camera."""
        return self.members.camera

    @property
    def baseline(self) -> float | None:
        """The stereo baseline (None: RGB-D)."""
        return self.members.baseline

    @property
    def keyframes(self) -> Sequence[WindowKeyframe]:
        """The members, oldest first."""
        return self.members.keyframes

    @property
    def targets(self) -> list[list[int]]:
        """Per host (position), its targets' positions (the members', or chosen by
        :func:`visible_targets` at the first call and kept)."""
        if self.members.targets is None:
            chosen = visible_targets(self.camera, self.keyframes, self.config)
            object.__setattr__(self, "members", dataclasses.replace(self.members, targets=chosen))
        assert self.members.targets is not None
        return self.members.targets

    def keyframe_keys(self, keyframe: WindowKeyframe) -> list[int]:
        """The keys of ``keyframe``'s variables: its pose, its affine, then one per :attr:`keyframe_kinds`
        present in :attr:`variables`."""
        extra = [gtsam.symbol(kind, keyframe.index) for kind in self.keyframe_kinds]
        return [pose_key(keyframe.index), affine_key(keyframe.index)] + [k for k in extra if self.variables.exists(k)]

    @property
    def config(self) -> WindowConfig:
        """The window's settings."""
        return self.settings.config

    @property
    def rig_offset(self) -> FloatArray | None:
        """The rig offset's start when it is a variable, else None."""
        return None if self.rig is None else np.asarray(self.rig.offset, dtype=float).reshape(2)

    def values(self) -> gtsam.Values:
        """The keyframes' poses and affines and :attr:`variables`, as GTSAM ``Values``."""
        v = gtsam.Values()
        for kf in self.keyframes:
            v.insert(pose_key(kf.index), kf.pose)
            v.insert(affine_key(kf.index), kf.affine)
        v.insert(self.variables)
        return v

    def n_residuals(self) -> int:
        """Point-target pairs in the photometric terms."""
        return sum(len(self.keyframes[h]) * len(ts) for h, ts in enumerate(self.targets))


#: the window's keyframes' :class:`HostSamples`, by ``id`` of their image: (image, pixels, pattern, camera, samples)
_SAMPLES: dict[int, tuple[weakref.ref, FloatArray, FloatArray, PinholeCamera, HostSamples]] = {}
#: :data:`_SAMPLES` is pruned of dead images beyond this many entries (a window holds a few keyframes)
_MAX_SAMPLES = 32


def host_samples(camera: PinholeCamera, keyframe: WindowKeyframe, pattern: FloatArray) -> HostSamples:
    """The keyframe's :class:`factors.host_points.HostSamples` (host intensities and bearings at its
    points' pattern): sampled once and kept while the keyframe's image lives, for its host factors of
    every solve, the marginalisation and the rig tests (the same arrays: they depend only on the
    image, the pixels, the pattern and the camera, checked at every use)."""
    key = id(keyframe.image)
    hit = _SAMPLES.get(key)
    if (hit is not None and hit[0]() is keyframe.image and hit[3] is camera and np.array_equal(hit[1], keyframe.pixels)
            and np.array_equal(hit[2], pattern)):
        return hit[4]
    samples = HostSamples.of(camera, keyframe.pixels, keyframe.image, pattern)
    if len(_SAMPLES) >= _MAX_SAMPLES:
        for k in [k for k, v in _SAMPLES.items() if v[0]() is None]:
            del _SAMPLES[k]
        while len(_SAMPLES) >= _MAX_SAMPLES:  # all alive: the oldest goes
            del _SAMPLES[next(iter(_SAMPLES))]
    _SAMPLES[key] = (weakref.ref(keyframe.image), np.array(keyframe.pixels, dtype=float), np.array(pattern, dtype=float),
                     camera, samples)
    return samples


@timed("window_build")
def host_factor(problem: WindowProblem, h: int, targets: Sequence[int] | None = None) -> HostPointsFactor:
    """The :class:`HostPointsFactor` of host ``problem.keyframes[h]`` observed in ``targets``
    (positions; default the problem's), weighed by the settings' photometric model; with the rig
    variable its stereo term has the rig offset (:func:`gtvo.core.keys.rig_offset_key`); the host
    factors share the settings' ``jacobian_budget`` (:class:`factors.smart.JacobianBudget`)."""
    keyframes, config, photometric = problem.keyframes, problem.config, problem.settings.photometric
    targets = problem.targets[h] if targets is None else targets
    kh = keyframes[h]
    factor = HostPointsFactor(
        pose_key(kh.index), [pose_key(keyframes[t].index) for t in targets], problem.camera, kh.pixels,
        kh.inverse_depth, kh.image, [keyframes[t].image for t in targets], kh.variance,
        sigma_intensity=photometric.sigma_intensity, huber_k=photometric.huber_k, affine_host_key=affine_key(kh.index),
        affine_target_keys=[affine_key(keyframes[t].index) for t in targets], depth_prior=kh.depth_prior,
        pattern=photometric.pattern_array, right_image=kh.right,
        baseline=problem.baseline if kh.right is not None else None,
        lambda_stereo=config.lambda_stereo, stereo_affine=kh.stereo_affine,
        prior_inverse_depth=kh.prior_inverse_depth,
        rig_key=rig_offset_key() if problem.rig is not None and kh.right is not None else None,
        jacobian_budget=problem.settings.jacobian_budget,
        host_samples=host_samples(problem.camera, kh, photometric.pattern_array))
    if problem.settings.jacobian_budget is None:
        _start_from_kept(problem, h, targets, factor)
    return factor


def _start_from_kept(problem: WindowProblem, h: int, targets: Sequence[int], factor: HostPointsFactor) -> None:
    """Give ``factor`` (host ``h`` in ``targets``) the residuals at the problem's state that an
    earlier pass of its host computed there (:func:`gtvo.window.residual_memo.recall`): its
    first evaluation, at that state, does not compute them again."""
    keyframes = problem.keyframes
    members = [keyframes[h]] + [keyframes[t] for t in targets]
    poses = [kf.pose for kf in members]
    affines = [kf.affine for kf in members]
    offset = problem.rig_offset if factor.rig_key is not None else None
    lins = residual_memo.recall(factor.points, keyframes[h].image,
                                residual_memo.HostState(poses, affines, factor.depths, offset))
    if lins is not None:
        vectors = (affines if factor.with_affine else []) + ([] if offset is None else [offset])
        factor.take_residuals(poses, vectors, lins)


@timed("window_build")
def build_graph(problem: WindowProblem) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, dict[int, HostPointsFactor]]:
    """GTSAM's graph of the problem: its first ``host_position`` factors (affine, gauge and motion
    priors), the host factors (one per host with targets, in runs of the settings' ``stack``), the
    marginalisation prior (``gtsam.LinearContainerFactor`` s), then the rest of its factors.

    Returns ``(graph, values, host_factors)`` with ``host_factors[position] = factor``.
    """
    hosts = {h: host_factor(problem, h) for h, ts in enumerate(problem.targets) if ts}
    graph = gtsam.NonlinearFactorGraph()
    for i in range(problem.host_position):
        graph.add(problem.factors.at(i))
    for f in stacked(list(hosts.values()), problem.settings.stack):
        graph.add(f)
    if problem.marginal is not None:
        for f in problem.marginal.nonlinear_factors():
            graph.add(f)
    for i in range(problem.host_position, problem.factors.size()):
        graph.add(problem.factors.at(i))
    return graph, problem.values(), hosts
