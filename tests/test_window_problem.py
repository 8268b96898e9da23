"""The window problem (gtvo.window.problem): one value for both solvers, one graph of the non-host
factors that both consume, and no function of the window or the refinement with a long argument list."""

from __future__ import annotations

import copy
import importlib
import inspect
import pkgutil

import gtsam
import numpy as np
import pytest

import gtvo.refinement
import gtvo.window
from factors.gtsam_factors import PythonFactor
from factors.params import PhotometricConfig
from gtvo.core.keys import pose_key
from gtvo.window import (WindowConfig, WindowMembers, WindowProblem, WindowSettings, build_graph, marginalize,
                         solve_gtsam, solve_handrolled, window_cost)
from tests.test_window import _keyframes, seq  # noqa: F401 (a fixture)

#: The most parameters a function of the window or the refinement takes (the problem carries the rest).
MAX_PARAMETERS = 5
NO_HUBER = PhotometricConfig(huber_k=None)
#: A test variable kind per keyframe (a vector of 3: "a velocity"), as a new factor would add one.
KIND = "w"


def _functions(package):
    """Every function and method written in ``package``'s modules (not those a dataclass generates)."""
    for info in pkgutil.iter_modules(package.__path__):
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        for name, obj in vars(module).items():
            if getattr(obj, "__module__", None) != module.__name__:
                continue
            members = [(name, obj)] if inspect.isfunction(obj) else (
                [(f"{name}.{n}", m) for n, m in vars(obj).items()] if inspect.isclass(obj) else [])
            for qual, f in members:
                f = inspect.unwrap(getattr(f, "__func__", f))
                if inspect.isfunction(f) and f.__code__.co_filename == module.__file__:
                    yield f"{module.__name__}.{qual}", f


def _parameter_count(f) -> int:
    return len([p for p in inspect.signature(f).parameters if p not in ("self", "cls")])


@pytest.mark.parametrize("package", [gtvo.window, gtvo.refinement], ids=lambda p: p.__name__)
def test_no_function_of_the_window_or_the_refinement_takes_more_than_five_parameters(package):
    functions = dict(_functions(package))
    assert len(functions) > 10  # the walk finds them (methods too)
    long = {name: _parameter_count(f) for name, f in functions.items() if _parameter_count(f) > MAX_PARAMETERS}
    assert not long, f"more than {MAX_PARAMETERS} parameters: {long}"


def test_the_parameter_count_sees_a_long_function():
    def long(a, b, c, d, e, f):  # noqa: ARG001
        return None

    assert _parameter_count(long) == 6 > MAX_PARAMETERS


class PositionPrior(PythonFactor):
    """A test factor on one keyframe's pose: its position ``t`` should be ``p`` (sigma 1 cm)."""

    def __init__(self, key: int, p: np.ndarray) -> None:
        self.key, self.p = key, np.asarray(p, dtype=float)
        super().__init__(gtsam.noiseModel.Isotropic.Sigma(3, 0.01), [key])

    def _evaluate(self, this, values, H):
        T = values.atPose3(self.key)
        if H is not None:
            H[0] = np.hstack([np.zeros((3, 3)), T.rotation().matrix()])
        return np.asarray(T.translation(), dtype=float) - self.p


def _problem(seq, keyframes, with_kind: bool) -> WindowProblem:
    """A window problem with a caller's factor (a position prior on the last keyframe) and, with
    ``with_kind``, a new variable per keyframe (``KIND``) tied to the keyframe's position by a
    between-vector factor and held by a prior on the first."""
    problem = WindowProblem.build(WindowMembers(seq.camera.left, seq.camera.baseline, keyframes),
                                  WindowSettings(WindowConfig(max_iterations=40, relative_tolerance=1e-12), NO_HUBER))
    last = keyframes[-1]
    problem.factors.add(PositionPrior(pose_key(last.index), np.asarray(seq.gt_poses[last.index])[:3, 3] + 0.01))
    if with_kind:
        problem.keyframe_kinds.append(KIND)
        for kf in keyframes:
            problem.variables.insert(gtsam.symbol(KIND, kf.index), np.asarray(kf.pose.translation(), dtype=float))
            problem.factors.add(TiedVector(gtsam.symbol(KIND, kf.index), pose_key(kf.index)))
    return problem


class TiedVector(PythonFactor):
    """A test factor: a vector variable equals its keyframe's position (sigma 0.1 m)."""

    def __init__(self, vector_key: int, key: int) -> None:
        self.vector_key, self.key = vector_key, key
        super().__init__(gtsam.noiseModel.Isotropic.Sigma(3, 0.1), [vector_key, key])

    def _evaluate(self, this, values, H):
        v, T = values.atVector(self.vector_key), values.atPose3(self.key)
        if H is not None:
            H[0] = np.eye(3)
            H[1] = -np.hstack([np.zeros((3, 3)), T.rotation().matrix()])
        return np.asarray(v, dtype=float) - np.asarray(T.translation(), dtype=float)


@pytest.mark.slow
@pytest.mark.parametrize("with_kind", [False, True])
def test_both_solvers_consume_a_callers_factor_and_variable_from_the_one_graph(seq, with_kind):
    """A factor added to the problem's graph (and a new vector variable per keyframe) is part of
    both solvers' cost: the same cost at the start (graph error == hand-rolled cost), the same
    optimum, and the caller's variable comes back in the result's ``variables``."""
    kfs = _keyframes(seq, [0, 2, 4, 6], perturb=(0.002, 0.006))
    graph, values, _ = build_graph(_problem(seq, kfs, with_kind))
    cost = window_cost(_problem(seq, copy.deepcopy(kfs), with_kind))
    assert graph.error(values) == pytest.approx(cost, rel=1e-9)
    plain = window_cost(WindowProblem.build(WindowMembers(seq.camera.left, seq.camera.baseline, kfs),
                                            WindowSettings(WindowConfig(), NO_HUBER)))
    assert cost > plain  # the caller's factors add to the cost
    a, b = copy.deepcopy(kfs), copy.deepcopy(kfs)
    ra, rb = solve_gtsam(_problem(seq, a, with_kind)), solve_handrolled(_problem(seq, b, with_kind))
    assert ra.cost == pytest.approx(rb.cost, rel=1e-4)
    for ka, kb in zip(a, b):
        assert np.abs(ka.pose.localCoordinates(kb.pose)).max() < 3e-5
    if with_kind:
        key = gtsam.symbol(KIND, a[1].index)
        np.testing.assert_allclose(ra.variables.atVector(key), rb.variables.atVector(key), atol=1e-4)
        np.testing.assert_allclose(ra.variables.atVector(key), a[1].pose.translation(), atol=0.05)


@pytest.mark.slow
def test_the_marginalisation_eliminates_a_keyframes_own_variables_and_keeps_the_others(seq):
    kfs = _keyframes(seq, [0, 2, 4, 6], perturb=(0.002, 0.006))
    problem = _problem(seq, kfs, True)
    w = [gtsam.symbol(KIND, kf.index) for kf in kfs]
    problem.factors.add(gtsam.BetweenFactorVector(w[0], w[1], np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
    prior = marginalize(problem, 0)
    assert w[0] not in prior.keys and pose_key(kfs[0].index) not in prior.keys  # eliminated with its keyframe
    assert w[1] in prior.keys and pose_key(kfs[1].index) in prior.keys  # what it said about them: kept
    assert w[2] not in prior.keys  # not connected to the leaving keyframe
    assert prior.H.shape == (sum(prior.dims),) * 2 and dict(zip(prior.keys, prior.dims))[w[1]] == 3


def test_the_problem_lists_its_factors_and_puts_the_hosts_after_the_priors(seq):
    kfs = _keyframes(seq, [0, 2, 4], points=100, timed=True)
    problem = WindowProblem.build(WindowMembers(seq.camera.left, seq.camera.baseline, kfs))
    # affine priors (3), the gauge prior (pose, affine), one motion prior; nothing after the hosts
    assert problem.factors.size() == 6 and problem.host_position == 6 and list(problem.gauge_factors) == [3, 4]
    graph, values, hosts = build_graph(problem)
    assert graph.size() == 6 + len(hosts) and values.size() == 6
    assert problem.targets == gtvo.window.visible_targets(seq.camera.left, kfs, WindowConfig())


def test_seen_in_targets_is_seen_in_per_target_to_the_bit():
    """The host's points checked against all targets at once are the one-target checks, point for point,
    also at the image border and behind the camera."""
    from gtvo.core.camera import PinholeCamera
    from gtvo.window.problem import seen_in, seen_in_targets

    rng = np.random.default_rng(7)
    cam = PinholeCamera(400.0, 400.0, 320.0, 240.0, 640, 480)

    class Frame:  # what seen_in reads of a keyframe
        def __init__(self, pose):
            self.pose = pose

    targets = [Frame(gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.3, 3)), rng.normal(0, 2, 3))) for _ in range(6)]
    Xw = rng.normal(0, 5, (500, 3)) + [0, 0, 6]
    T = np.stack([t.pose.inverse().matrix() for t in targets])
    batch = seen_in_targets(cam, Xw, T)
    assert batch.shape == (6, 500) and batch.any() and not batch.all()
    for k, t in enumerate(targets):
        assert np.array_equal(batch[k], seen_in(cam, Frame(gtsam.Pose3()), t, Xw))


def test_host_samples_are_kept_per_keyframe_and_checked_at_every_use():
    """A keyframe's host samples are sampled once and reused while its image, pixels, pattern and
    camera are the same (the values of a fresh sampling); any change samples again."""
    from factors.host_points import HostSamples
    from factors.photometric import PATTERN_DSO8, GradientImage
    from gtvo.core.camera import PinholeCamera
    from gtvo.window.problem import host_samples

    rng = np.random.default_rng(3)
    cam = PinholeCamera(100.0, 100.0, 40.0, 30.0, 80, 60)

    class Frame:  # what host_samples reads of a keyframe
        def __init__(self):
            self.image = GradientImage(rng.uniform(10, 240, (60, 80)))
            self.pixels = np.c_[rng.uniform(5, 75, 30), rng.uniform(5, 55, 30)]

    kf = Frame()
    a = host_samples(cam, kf, PATTERN_DSO8)
    assert host_samples(cam, kf, PATTERN_DSO8) is a
    fresh = HostSamples.of(cam, kf.pixels, kf.image, PATTERN_DSO8)
    for name in ("intensity", "valid", "bearings"):
        assert np.array_equal(getattr(a, name), getattr(fresh, name))
    assert host_samples(cam, kf, PATTERN_DSO8[:4]) is not a
    kf.pixels = kf.pixels + 1.0
    b = host_samples(cam, kf, PATTERN_DSO8)
    assert b is not a and np.array_equal(b.bearings, HostSamples.of(cam, kf.pixels, kf.image, PATTERN_DSO8).bearings)
    kf.image = GradientImage(rng.uniform(10, 240, (60, 80)))
    assert host_samples(cam, kf, PATTERN_DSO8) is not b
    assert host_samples(PinholeCamera(100.0, 100.0, 40.0, 30.0, 80, 60), kf, PATTERN_DSO8) is not b


def test_problems_over_the_same_keyframes_share_their_motion_factors(seq):  # noqa: F811
    """A motion factor holds no state: two problems over the same keyframes get the same objects,
    other time steps another one."""
    from gtvo.window.problem import motion_factors  # noqa: PLC0415

    kfs = _keyframes(seq, [0, 2, 4, 6], points=30)
    for i, kf in enumerate(kfs):
        kf.timestamp = 0.1 * i
    cfg = WindowConfig()
    first, second = motion_factors(kfs, cfg), motion_factors(kfs, cfg)
    assert len(first) == 2 and all(a[1] is b[1] for a, b in zip(first, second))
    kfs[3].timestamp = 0.35
    third = motion_factors(kfs, cfg)
    assert third[0][1] is first[0][1] and third[1][1] is not first[1][1]
    assert third[1][1].dt == (kfs[2].timestamp - kfs[1].timestamp, kfs[3].timestamp - kfs[2].timestamp)
