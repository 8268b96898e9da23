"""The window's residuals kept across its solves (gtvo.window.residual_memo): what a host's last pass
computed is given back at a byte-equal state and only there, and a window solved with them is the
window solved without them, to the bit."""

from __future__ import annotations

import copy
import dataclasses
import gc

import numpy as np
import pytest

import factors.host_points as host_points
from gtvo.window import WindowConfig, build_graph, marginalize, solve_gtsam, solve_handrolled
from gtvo.window import residual_memo
from gtvo.window.residual_memo import HostState
from tests._window_problem import problem
from tests.test_window import _keyframes, seq  # noqa: F401 (a fixture)

ARRAYS = ("residual", "valid", "J_depth", "J_host", "J_affine_host", "uv_target", "J_offset")


def _same(a, b) -> None:
    """Two linearisations hold the same bits (and the same pair pose and gain)."""
    for name in ARRAYS:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.tobytes() == y.tobytes(), name
    assert (a.T_target_host is None) == (b.T_target_host is None)
    if a.T_target_host is not None:
        assert np.array_equal(a.T_target_host, b.T_target_host) and a.brightness_gain == b.brightness_gain


@pytest.fixture
def host(seq):  # noqa: F811
    """A host factor's points, its image and a state of three keyframes (host 0 seen in 1 and 2)."""
    cam = seq.camera
    kfs = _keyframes(seq, [0, 2, 4], points=120)
    _, _, hosts = build_graph(problem(cam.left, cam.baseline, kfs, WindowConfig(), None, [[1, 2], [], []]))
    points = hosts[0].points
    state = HostState([k.pose for k in kfs], [k.affine for k in kfs], kfs[0].inverse_depth.copy())
    return points, kfs, state


def _fresh(points, state):
    """A whole pass at ``state`` (a copy of its outputs: the pass buffers are reused)."""
    return [None if lin is None else copy.deepcopy(lin)
            for lin in points.residuals(state.poses, state.affines, state.d, offset=state.offset)]


def test_the_kept_residuals_come_back_at_the_same_state_only(host):
    points, kfs, state = host
    kept = _fresh(points, state)
    residual_memo.remember(points, kfs[0].image, state, kept)
    again = residual_memo.recall(points, kfs[0].image, state)
    assert again is not None and len(again) == len(kept)
    for a, b in zip(again, kept):
        _same(a, b)
    assert again[0].J_host is kept[0].J_host  # kept, not computed again
    # another inverse depth: nothing comes back (every residual depends on it)
    d = state.d.copy()
    d[3] *= 1.0 + 1e-12
    assert residual_memo.recall(points, kfs[0].image, HostState(state.poses, state.affines, d)) is None
    # another image object, even an equal one: nothing
    assert residual_memo.recall(points, copy.copy(kfs[0].image), state) is None


def test_a_target_that_moved_is_computed_again_the_others_are_kept(host):
    points, kfs, state = host
    residual_memo.remember(points, kfs[0].image, state, _fresh(points, state))
    poses = list(state.poses)
    poses[2] = poses[2].retract(np.r_[0.0, 0.0, 0.0, 0.003, 0.0, 0.0])
    moved = HostState(poses, state.affines, state.d)
    mixed = residual_memo.recall(points, kfs[0].image, moved)
    fresh = _fresh(points, moved)
    assert mixed is not None
    for a, b in zip(mixed, fresh):
        _same(a, b)  # the kept target's and the computed one's bits are a whole pass's
    # the stacked residuals the compiled point costs read are those of the items
    assert np.array_equal(mixed.residual_stack, np.stack([lin.residual for lin in mixed if lin is not None]))
    assert not np.array_equal(mixed[1].residual, _fresh(points, state)[1].residual)


def test_a_rig_offset_changes_only_the_stereo_terms_key(host):
    points, kfs, state = host
    residual_memo.remember(points, kfs[0].image, state, _fresh(points, state))
    shifted = HostState(state.poses, state.affines, state.d, np.array([0.0, 0.5]))
    out = residual_memo.recall(points, kfs[0].image, shifted)
    fresh = _fresh(points, shifted)
    for a, b in zip(out, fresh):
        _same(a, b)


def test_forget_and_dead_images_drop_the_entries(host):
    points, kfs, state = host
    residual_memo.remember(points, kfs[0].image, state, _fresh(points, state))
    residual_memo.forget(kfs[0].image)
    assert residual_memo.recall(points, kfs[0].image, state) is None
    residual_memo.remember(points, kfs[0].image, state, _fresh(points, state))
    key = id(kfs[0].image)
    assert key in residual_memo._PASSES
    kfs[0].image = None  # the keyframe's image goes: its entry goes at the next pruning
    gc.collect()
    residual_memo._prune()
    assert key not in residual_memo._PASSES
    assert len(residual_memo._PASSES) < residual_memo.MAX_HOSTS


@pytest.mark.slow
@pytest.mark.parametrize("solver", [solve_gtsam, solve_handrolled], ids=["gtsam", "handrolled"])
def test_a_window_solved_from_kept_residuals_is_the_window_solved_without(seq, solver, monkeypatch):  # noqa: F811
    """Two solves in a row (a new keyframe between them, so the hosts' targets change), then the
    marginalisation: with the first solve's residuals kept, the second solve does fewer passes and
    ends at the same bits as with nothing kept."""
    cam = seq.camera
    cfg = WindowConfig(max_iterations=4)
    base = _keyframes(seq, [0, 2, 4, 6], perturb=(0.002, 0.006), points=150)

    def run(keep: bool):
        # the same images (the kept residuals apply), the states copied
        kfs = [dataclasses.replace(k, inverse_depth=k.inverse_depth.copy(), affine=k.affine.copy()) for k in base]
        solver(problem(cam.left, cam.baseline, kfs[:3], cfg, keep_residuals=True))
        if not keep:
            residual_memo._PASSES.clear()
        calls = []
        real = host_points.HostPoints.residuals
        monkeypatch.setattr(host_points.HostPoints, "residuals",
                            lambda self, *a, **k: calls.append(k.get("rows", a[3] if len(a) > 3 else None)) or
                            real(self, *a, **k))
        solver(problem(cam.left, cam.baseline, kfs, cfg, keep_residuals=True))
        marginal = marginalize(problem(cam.left, cam.baseline, kfs, cfg), 0)
        monkeypatch.setattr(host_points.HostPoints, "residuals", real)
        residual_memo._PASSES.clear()
        return kfs, marginal, sum(rows is None for rows in calls)

    with_kept, m1, full1 = run(True)
    without, m2, full2 = run(False)
    assert full1 < full2  # whole passes saved: the first cost pass of the old hosts, the marginalisation's
    for a, b in zip(with_kept, without):
        assert np.asarray(a.pose.matrix()).tobytes() == np.asarray(b.pose.matrix()).tobytes()
        assert a.inverse_depth.tobytes() == b.inverse_depth.tobytes()
        assert np.asarray(a.affine).tobytes() == np.asarray(b.affine).tobytes()
    assert m1.H.tobytes() == m2.H.tobytes() and m1.eta.tobytes() == m2.eta.tobytes()
