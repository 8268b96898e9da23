"""HostPoints, the per-host linearisation shared by both window solvers: independent of where the
caller's state puts its blocks, back-substitution, the safeguarded depth step, frozen weights.
(Its reduced system against the per-point graph: tests/test_factors_smart.py; the two solvers
built on it against each other: tests/test_window.py.)"""

from __future__ import annotations

import copy
import dataclasses

import gtsam
import numpy as np
import pytest

from factors.host_points import HostPoints
from factors.photometric import PATTERN_DSO8, GradientImage
from gtvo.errors import InputError
from tests._factors_synthetic import SinusoidImage, small_camera


def _problem(seed: int = 0, stereo: bool = True, n: int = 40):
    """A host with two targets (and a right image): ``(points, poses, affines, d)``."""
    rng = np.random.default_rng(seed)
    cam = small_camera()
    px = np.c_[rng.uniform(25, 135, n), rng.uniform(25, 95, n)]
    d = rng.uniform(0.2, 1.5, n)
    V = rng.uniform(1e-4, 1e-2, n)
    targets = [SinusoidImage(seed=seed + 2), SinusoidImage(seed=seed + 3)]
    pts = HostPoints(cam, px, SinusoidImage(seed=seed + 1), targets, V, d * (1 + 0.05 * rng.normal(size=n)), sigma_intensity=8.0, huber_k=2.0, pattern=PATTERN_DSO8,
                     depth_prior=True, right_image=SinusoidImage(seed=seed + 4) if stereo else None,
                     baseline=0.2 if stereo else None, lambda_stereo=0.7, stereo_affine=(0.05, 2.0))
    poses = [gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.02, 3)), rng.normal(0, 0.05, 3)) for _ in range(3)]
    affines = [rng.normal(0, 0.1, 2) for _ in range(3)]
    return pts, poses, affines, d


def _local_columns(t: int) -> np.ndarray:
    """All poses, then all affines (the smart factor's order), for host + 2 targets."""
    return np.r_[0:6, 18:20, 6 * (1 + t):6 * (2 + t), 18 + 2 * (1 + t):20 + 2 * (1 + t)]


@pytest.mark.parametrize("huber_k,with_affine,stereo", [(2.0, True, False), (None, True, True), (2.0, False, True)])
def test_fused_pair_terms_equal_the_numpy_loop(huber_k, with_affine, stereo):
    """``linearize``'s compiled per-pair call (the residuals carry their pair's pose and gain) adds
    the same terms as its numpy loop (residuals without them: the general sums), with and
    without affines; a caller's column blocks that do not fit are refused, not summed."""
    pts, poses, affines, d = _problem(stereo=stereo)
    pts.huber_k = huber_k
    pts.with_affine = with_affine
    lins = pts.residuals(poses, affines, d)
    assert all(lin.T_target_host is not None for lin in lins[:-1])
    plain = [dataclasses.replace(lin, T_target_host=None, brightness_gain=None) for lin in lins[:-1]] + [lins[-1]]
    if with_affine:
        cols = [_local_columns(t) for t in range(2)]
    else:  # poses only: host, then the target
        cols = [np.r_[0:6, 6 * (1 + t):6 * (2 + t)] for t in range(2)]
    if with_affine:
        with pytest.raises(InputError, match="columns"):
            pts.linearize(lins, d, np.zeros((24, 24)), np.zeros(24), [c[:12] for c in cols])
    H1, g1, H2, g2 = np.zeros((24, 24)), np.zeros(24), np.zeros((24, 24)), np.zeros(24)
    s1 = pts.linearize(lins, d, H1, g1, cols)
    s2 = pts.linearize(plain, d, H2, g2, cols)
    np.testing.assert_allclose(H1, H2, rtol=0, atol=1e-12 * np.abs(H2).max())
    np.testing.assert_allclose(g1, g2, rtol=0, atol=1e-12 * np.abs(g2).max())
    for name in ("H_pd", "H_dd", "g_d", "point_cost"):
        a, b = getattr(s1, name), getattr(s2, name)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
    assert np.array_equal(s1.active, s2.active)


@pytest.mark.parametrize("stereo", [False, True])
def test_linearization_does_not_depend_on_the_callers_layout(stereo):
    """The same host linearised into the smart factor's 24-entry state and into a 5-keyframe
    window state (host at position 3, targets at 0 and 4, 8 entries each, already holding other
    terms) gives the same reduced system and per-point blocks, entry for entry."""
    pts, poses, affines, d = _problem(stereo=stereo)
    lins = pts.residuals(poses, affines, d)
    H1, g1 = np.zeros((24, 24)), np.zeros(24)
    s1 = pts.linearize(lins, d, H1, g1, [_local_columns(t) for t in range(2)])

    rng = np.random.default_rng(5)
    A = rng.normal(size=(40, 40))
    H0, g0 = A @ A.T, rng.normal(size=40)
    H2, g2 = H0.copy(), g0.copy()
    pos = [3, 0, 4]  # host, targets
    s2 = pts.linearize(lins, d, H2, g2, [np.r_[8 * pos[0]:8 * pos[0] + 8, 8 * p:8 * p + 8] for p in pos[1:]])
    # window entry of each smart-factor entry: poses first, then affines
    where = np.r_[[8 * p + i for p in pos for i in range(6)], [8 * p + 6 + i for p in pos for i in range(2)]]
    scale = np.abs(H1).max()
    np.testing.assert_allclose((H2 - H0)[np.ix_(where, where)], H1, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose((g2 - g0)[where], g1, rtol=0, atol=1e-12 * np.abs(g1).max())
    others = np.setdiff1d(np.arange(40), where)
    assert np.array_equal(H2[others], H0[others]) and np.array_equal(g2[others], g0[others])
    np.testing.assert_array_equal(s2.H_pd[:, where], s1.H_pd)
    assert not s2.H_pd[:, others].any()
    for name in ("H_dd", "g_d", "active", "point_cost", "d"):
        np.testing.assert_array_equal(getattr(s2, name), getattr(s1, name))
    assert s1.point_cost.sum() == pytest.approx(pts.point_costs(lins, d).sum(), rel=1e-14)


def test_elimination_skips_the_points_without_curvature():
    """Points with no curvature (``H_dd`` 0: seen nowhere, no prior) are not eliminated and keep their
    depth; the others' Schur complement is the one of the active points alone, and with all points
    active it is the same product as with the rows selected (to the bit)."""
    pts, poses, affines, d = _problem(seed=2)
    lins = pts.residuals(poses, affines, d)
    H, g = np.zeros((24, 24)), np.zeros(24)
    s = pts.linearize(lins, d, H, g, [_local_columns(t) for t in range(2)])
    assert s.active.all()
    H_full = H + s.H_pd.T @ (s.H_pd / s.H_dd[:, None])  # undo: the system before the elimination
    g_full = g + s.H_pd.T @ (s.g_d / s.H_dd)
    idle = np.arange(0, len(d), 5)
    H_dd = s.H_dd.copy()
    H_dd[idle] = 0.0
    system = dataclasses.replace(s, H_dd=H_dd, active=np.ones(len(d), dtype=bool))
    H2, g2 = H_full.copy(), g_full.copy()
    out = HostPoints._eliminate(system, H2, g2)
    keep = np.setdiff1d(np.arange(len(d)), idle)
    assert np.array_equal(np.flatnonzero(~out.active), idle) and np.all(out.H_dd[idle] == 1.0)
    L = s.H_pd[keep] / s.H_dd[keep, None]
    np.testing.assert_allclose(H2, H_full - L.T @ s.H_pd[keep], rtol=0, atol=1e-9 * np.abs(H_full).max())
    np.testing.assert_allclose(g2, g_full - L.T @ s.g_d[keep], rtol=0, atol=1e-9 * np.abs(g_full).max())
    np.testing.assert_array_equal(out.back_substitute(np.zeros(24))[idle], d[idle])
    # all active: the same numbers as the row-selected products
    H3, g3 = H_full.copy(), g_full.copy()
    HostPoints._eliminate(dataclasses.replace(s, active=np.ones(len(d), dtype=bool)), H3, g3)
    a = np.ones(len(d), dtype=bool)
    L = s.H_pd[a] / s.H_dd[a, None]
    assert H3.tobytes() == (H_full - L.T @ s.H_pd[a]).tobytes() and g3.tobytes() == (g_full - L.T @ s.g_d[a]).tobytes()


def test_back_substitution_is_the_depth_rows_of_the_newton_system():
    """``H_pd dx + H_dd dd = -g_d`` for every active point, depths kept >= 0.1 d."""
    pts, poses, affines, d = _problem(seed=1)
    H, g = np.zeros((24, 24)), np.zeros(24)
    s = pts.linearize(pts.residuals(poses, affines, d), d, H, g, [_local_columns(t) for t in range(2)])
    dx = np.linalg.solve(H + 1e-6 * np.eye(24), -g)
    dd = s.back_substitute(dx) - d
    a = s.active & (dd > -0.9 * d)  # not clamped
    assert a.sum() > 0.8 * len(d)
    np.testing.assert_allclose(s.H_pd[a] @ dx + s.H_dd[a] * dd[a], -s.g_d[a], rtol=1e-9,
                               atol=1e-9 * np.abs(s.g_d).max())
    big = s.back_substitute(1e6 * dx)
    assert np.all(big >= 0.1 * d - 1e-15)
    assert s.newton_decrease() == pytest.approx(0.5 * np.sum(s.g_d[s.active] ** 2 / s.H_dd[s.active]))


def test_safeguard_keeps_per_point_the_cheaper_depth():
    """At a trial state, a point whose cost rose above its cost at the linearisation point keeps
    whichever of its new and old depth costs less; the others keep the new depth."""
    pts, poses, affines, d = _problem(seed=2)
    H, g = np.zeros((24, 24)), np.zeros(24)
    s = pts.linearize(pts.residuals(poses, affines, d), d, H, g, [_local_columns(t) for t in range(2)])
    rng = np.random.default_rng(3)
    dx = np.linalg.solve(H + 1e-3 * np.diag(np.diag(H)), -g) + rng.normal(0, 0.005, 24)
    P = [p.retract(dx[6 * i:6 * i + 6]) for i, p in enumerate(poses)]
    A = [a + dx[18 + 2 * i:20 + 2 * i] for i, a in enumerate(affines)]
    d_new = s.back_substitute(dx)
    c, d_out, lins = pts.safeguard(P, A, s, d_new, pts.residuals(P, A, d_new))
    c_new = pts.point_costs(pts.residuals(P, A, d_new), d_new)
    c_old = pts.point_costs(pts.residuals(P, A, d), d)
    rose = c_new > s.point_cost
    assert rose.any()
    back = rose & (c_old < c_new)
    assert back.any() and not back[rose].all()  # (measured: 5 rose, 3 of them go back)
    np.testing.assert_array_equal(d_out, np.where(back, d, d_new))
    np.testing.assert_allclose(c, np.where(back, c_old, c_new), rtol=1e-12)
    np.testing.assert_allclose(pts.point_costs(lins, d_out), c, rtol=1e-12)  # lins belong to d_out
    # at dx = 0 the safeguarded cost cannot exceed the cost at the linearisation point
    d0 = s.back_substitute(np.zeros(24))
    c0 = pts.safeguard(poses, affines, s, d0, pts.residuals(poses, affines, d0))[0]
    assert c0.sum() <= s.point_cost.sum()


def test_weights_are_frozen_until_released():
    """W is evaluated once, at the first state given; release_weights re-evaluates it at the next."""
    pts, poses, affines, d = _problem(seed=3)
    c_a = pts.point_costs(pts.residuals(poses, affines, d), d)
    moved = [poses[0]] + [p.retract(np.r_[0, 0, 0, 0.05, -0.03, 0.04]) for p in poses[1:]]
    lins_b = pts.residuals(moved, affines, d)
    W_a = [w.copy() for w in pts.W]
    c_frozen = pts.point_costs(lins_b, d)
    assert all(np.array_equal(a, b) for a, b in zip(W_a, pts.W))
    pts.release_weights()
    c_released = pts.point_costs(lins_b, d)
    assert not np.allclose(c_frozen, c_released, rtol=1e-6)
    fresh = _problem(seed=3)[0]
    np.testing.assert_array_equal(fresh.point_costs(fresh.residuals(moved, affines, d), d), c_released)
    assert not np.allclose(c_a, c_released, rtol=1e-6)


def _gradient_problem(n: int = 60, rig: bool = True):
    """``_problem``'s host with plain GradientImage targets and right image (the compiled pass),
    some clipped pixels and some points behind or outside a target: ``(points, poses, affines, d)``."""
    rng = np.random.default_rng(7)
    cam = small_camera()

    def image(seed: int) -> GradientImage:
        s = SinusoidImage(seed=seed)
        u, v = np.meshgrid(np.arange(160.0), np.arange(120.0))
        img = s.sample(u, v)[0][..., 0]
        img[rng.integers(0, 120, 30), rng.integers(0, 160, 30)] = 255.0  # clipped pixels
        return GradientImage(img)

    px = np.c_[rng.uniform(5, 155, n), rng.uniform(5, 115, n)]
    d = rng.uniform(0.2, 1.5, n)
    d[:2] = (-0.5, np.nan)  # bad depths
    V = rng.uniform(1e-4, 1e-2, n)
    pts = HostPoints(cam, px, image(1), [image(2), image(3)], V, np.abs(np.nan_to_num(d, nan=1.0)) + 0.1,
                     sigma_intensity=8.0, huber_k=2.0, pattern=PATTERN_DSO8, depth_prior=True, right_image=image(4),
                     baseline=0.2, lambda_stereo=0.7, stereo_affine=(0.05, 2.0), rig=rig)
    poses = [gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.05, 3)), rng.normal(0, 0.3, 3)) for _ in range(3)]
    affines = [rng.normal(0, 0.1, 2) for _ in range(3)]
    return pts, poses, affines, d


def _assert_same_lins(a: list, b: list) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b):
        for f in dataclasses.fields(x):
            u, v = getattr(x, f.name), getattr(y, f.name)
            if isinstance(u, np.ndarray) or isinstance(v, np.ndarray):
                assert u is not None and v is not None, f.name
                assert u.shape == v.shape and u.tobytes() == v.tobytes(), f.name
            else:
                assert u == v, f.name


@pytest.mark.parametrize("jacobians", [True, False])
def test_compiled_pass_equals_the_per_target_calls_to_the_bit(jacobians):
    """``residuals``' compiled pass (one-thread path: buffers, rows read in place, pair poses once per
    state) gives the per-target calls' (``residual_calls``) values byte for byte: all points and
    some rows, with a rig offset, bad depths, clipped pixels, points outside a target; the point
    costs of its stacked residuals equal the per-term sums."""
    pts, poses, affines, d = _gradient_problem()
    offset = np.array([0.3, -0.2])
    full = pts.residuals(poses, affines, d, offset=offset, jacobians=jacobians)
    assert type(full).__name__ == "PassLinearizations"
    ref = [c() for c in pts.residual_calls(poses, affines, d, offset=offset, jacobians=jacobians)]
    _assert_same_lins(full, ref)
    assert sum(lin.n_outside + lin.n_behind for lin in full) > 0 and full[0].n_bad_depth == 2
    assert (full[-1].J_offset is not None) == jacobians
    rows = np.array([3, 0, 17, 42, 5], dtype=np.intp)
    part = pts.residuals(poses, affines, d, rows, offset=offset, jacobians=jacobians)
    _assert_same_lins(part, [c() for c in pts.residual_calls(poses, affines, d, rows, offset=offset,
                                                             jacobians=jacobians)])
    # the first pass is still intact (a pass never writes buffers a linearisation refers to)
    _assert_same_lins(full, ref)
    c = pts.point_costs(full, d)
    assert c.tobytes() == pts.point_costs(list(full), d).tobytes()  # a plain list: the per-term numpy sums
    cr = pts.point_costs(part, d, rows)
    assert cr.tobytes() == pts.point_costs(list(part), d, rows).tobytes() and np.array_equal(cr, c[rows])


def test_pass_buffers_are_reused_only_when_nothing_refers_to_them():
    """A pass writes into a buffer set no linearisation refers to: dropping a pass's results frees
    its set for the next pass, keeping any one of its arrays keeps it."""
    pts, poses, affines, d = _gradient_problem(rig=False)
    a = pts.residuals(poses, affines, d)
    first = id(a[0].residual.base)  # (an id: a reference would keep the set in use)
    del a
    b = pts.residuals(poses, affines, d * 1.01)
    assert id(b[0].residual.base) == first  # reused
    kept = b[1].J_host
    del b
    c = pts.residuals(poses, affines, d)
    assert id(c[0].residual.base) != first and id(kept.base) == first
    before = kept.copy()
    pts.residuals(poses, affines, d * 0.9)
    assert kept.tobytes() == before.tobytes()
    twin = copy.deepcopy(pts)  # a copy's buffers are new and free (its copied arrays are not views of them)
    assert all(not b.in_use() for b in twin._buffers) and len(twin._buffers) == len(pts._buffers)


@pytest.mark.parametrize("jacobians", [True, False])
def test_safeguard_in_place_equals_the_merge_of_an_evaluation_apart_to_the_bit(jacobians):
    """The safeguard on a compiled pass still in its buffers (the points that rose evaluated into
    other buffers, the rows of those that go back copied into the pass's own) gives the depths, costs and linearisations of the evaluation apart and
    ``keep_cheaper_depths``' merge (a plain list of copies takes that path), byte for byte, with a
    rig offset; a point whose depth did not move is not sent back."""
    pts, poses, affines, d = _gradient_problem()
    d = np.abs(np.nan_to_num(d, nan=1.0)) + 0.1
    offset = np.array([0.3, -0.2])
    H, g = np.zeros((26, 26)), np.zeros(26)
    s = pts.linearize(pts.residuals(poses, affines, d, offset=offset), d, H, g, [_local_columns(t) for t in range(2)],
                      np.array([24, 25]))
    dx = np.linalg.solve(H + 1e-3 * np.diag(np.diag(H)), -g) + np.random.default_rng(5).normal(0, 0.01, 26)
    P = [p.retract(dx[6 * i:6 * i + 6]) for i, p in enumerate(poses)]
    A = [a + dx[18 + 2 * i:20 + 2 * i] for i, a in enumerate(affines)]
    d_new = s.back_substitute(dx)
    d_new[7] = d[7]  # a depth that did not move
    o = offset + dx[24:]
    lins = pts.residuals(P, A, d_new, offset=o, jacobians=jacobians)
    apart = copy.deepcopy(list(lins))
    assert lins.writable_buffers(len(pts)) is lins.buffers
    assert copy.deepcopy(lins).writable_buffers(len(pts)) is None  # a copy's arrays are not its buffers'
    c1, d1, l1 = pts.safeguard(P, A, s, d_new, lins, o, jacobians=jacobians)
    c2, d2, l2 = pts.safeguard(P, A, s, d_new, apart, o, jacobians=jacobians)
    assert l1 is lins and type(l2) is list  # the two paths taken
    back = d1 != d_new
    assert back.sum() >= 3 and (~back & (c1 > s.point_cost)).any() and not back[7]
    assert c1.tobytes() == c2.tobytes() and d1.tobytes() == d2.tobytes()
    _assert_same_lins(l1, l2)
    assert (l1[0].J_host is not None) == jacobians and (l1[-1].J_offset is not None) == jacobians
    assert pts.point_costs(l1, d1).tobytes() == c1.tobytes()  # lins belong to the safeguarded depths
