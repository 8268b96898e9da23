"""Loop closing with GNC: a planted false loop is rejected, a true revisit is accepted (synthetic)."""

from __future__ import annotations

import numpy as np
import pytest

from gtvo.errors import InputError
from gtvo.core import lie
from gtvo.loops.closure_graph import LoopEdge, close_loops

ODO_INFO = np.diag([1e4] * 3 + [1e3] * 3)  # matches the simulated odometry noise (0.01 rad, 0.03 m)
LOOP_INFO = np.diag([1e4] * 3 + [1e2] * 3)


def _circle_run(n: int = 40, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth keyframes on a circle (radius 10 m) and a drifting VO estimate of them."""
    rng = np.random.default_rng(seed)
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, :3, :3] = lie.so3_exp(np.stack([np.zeros(n), np.zeros(n), ang], 1))
    gt[:, :3, 3] = np.stack([10 * np.cos(ang), 10 * np.sin(ang), 0.2 * np.sin(3 * ang)], 1)
    vo = [gt[0]]
    for k in range(n - 1):
        R, t = lie.se3_exp(np.r_[rng.normal(size=3) * 0.01, rng.normal(size=3) * 0.03][None])
        N = np.eye(4)
        N[:3, :3], N[:3, 3] = R[0], t[0]
        vo.append(vo[-1] @ np.linalg.inv(gt[k]) @ gt[k + 1] @ N)
    return gt, np.array(vo)


def _rmse(P: np.ndarray, gt: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((P[:, :3, 3] - gt[:, :3, 3]) ** 2, axis=1))))


def test_gnc_rejects_false_loop_and_accepts_true_one() -> None:
    gt, vo = _circle_run()
    n = len(gt)
    true_loop = LoopEdge(n - 1, 0, np.linalg.inv(gt[n - 1]) @ gt[0], LOOP_INFO)
    false_loop = LoopEdge(10, 30, np.eye(4), LOOP_INFO)  # "same place" across the circle: wrong
    res = close_loops(vo, [true_loop, false_loop], ODO_INFO, method="gnc")
    assert res.accepted.tolist() == [True, False]
    only_true = close_loops(vo, [true_loop], ODO_INFO, method="gnc")
    assert only_true.accepted.tolist() == [True]
    # the false loop changes nothing; the true one removes most of the drift
    assert np.allclose(res.poses, only_true.poses, atol=1e-4)
    assert _rmse(res.poses, gt) < 0.4 * _rmse(vo, gt)
    # without GNC a robust kernel alone lets the false loop bend the map
    huber = close_loops(vo, [true_loop, false_loop], ODO_INFO, method="huber")
    assert _rmse(huber.poses, gt) > 2 * _rmse(res.poses, gt)


def test_gnc_with_only_a_false_loop_keeps_the_vo() -> None:
    gt, vo = _circle_run(seed=1)
    res = close_loops(vo, [LoopEdge(5, 25, np.eye(4), LOOP_INFO)], ODO_INFO)
    assert res.accepted.tolist() == [False]
    assert np.allclose(res.poses, vo, atol=1e-6)


def test_loop_closure_bad_input() -> None:
    _, vo = _circle_run(n=5)
    with pytest.raises(InputError):
        close_loops(vo, [LoopEdge(0, 7, np.eye(4), LOOP_INFO)])
    with pytest.raises(InputError):
        close_loops(vo[:, :3], [])
    with pytest.raises(InputError):
        close_loops(vo, [], method="ransac")
