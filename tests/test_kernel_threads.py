"""Kernel threads (issue 34): ``gtvo.core.kernel_threads`` runs independent calls on a fixed pool,
results in order; the window's hosts compute each LM pass's residuals together on it, with the
same bytes as one thread (``factors.smart.shared_residual_passes``); batch jobs keep one thread."""

from __future__ import annotations

import copy
import dataclasses
import threading

import numpy as np
import pytest

from gtvo.config import OdometryConfig
from gtvo.core import kernel_threads
from gtvo.core.kernel_threads import map_independent, set_kernel_threads
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.odometry.window_worker import DEFAULT_WORKER_THREADS, worker_threads
from gtvo.window import WindowConfig, solve_gtsam
from tests.test_window import _keyframes
from tests._window_problem import problem


@pytest.fixture
def two_threads():
    set_kernel_threads(2)
    yield
    set_kernel_threads(1)


def test_one_thread_is_the_plain_loop():
    assert kernel_threads.kernel_threads() == 1
    names = []
    out = map_independent([lambda k=k: names.append(threading.current_thread().name) or k * k for k in range(5)])
    assert out == [0, 1, 4, 9, 16]
    assert set(names) == {threading.current_thread().name}


def test_two_threads_run_calls_at_once_and_keep_their_order(two_threads):
    both = threading.Barrier(2, timeout=300)  # passes only when two calls run at the same time (a generous
    #                                          timeout: a thread on a busy machine may start late)

    def call(k: int) -> int:
        if k < 2:
            both.wait()
        return 10 * k

    before = kernel_threads.pool_cpu_seconds()
    assert map_independent([lambda k=k: call(k) for k in range(6)]) == [0, 10, 20, 30, 40, 50]
    assert kernel_threads.pool_cpu_seconds() > before  # the pool thread's CPU is counted


def test_a_calls_exception_is_raised_and_a_nested_map_runs_inline(two_threads):
    def bad() -> None:
        raise ValueError("call 3 failed")

    with pytest.raises(ValueError, match="call 3 failed"):
        map_independent([lambda: 1, lambda: 2, lambda: 3, bad, lambda: 5])
    inner = map_independent([lambda: map_independent([lambda: 1, lambda: 2]) for _ in range(4)])
    assert inner == [[1, 2]] * 4


@pytest.mark.parametrize("bad", [0, -1, 1.5, True])
def test_bad_thread_counts_are_refused(bad):
    with pytest.raises(ValueError, match="kernel threads must be an integer >= 1"):
        set_kernel_threads(bad)


def test_window_with_two_kernel_threads_gives_the_same_bytes(monkeypatch):
    """One LM window solved with one thread and with two: the same poses, depths, covariances and
    cost, byte for byte (one thread: the hosts' compiled passes; two: their per-target calls), and
    with two threads the hosts' residual calls run together (one map of more calls than one host has)."""
    seq = make_synthetic_sequence(8, width=240, height=180, step_m=0.1)
    kfs = _keyframes(seq, [0, 2, 4, 6], perturb=(0.002, 0.006), points=150)
    cfg = WindowConfig(max_iterations=4)
    cam = seq.camera
    sizes: list[int] = []
    real = kernel_threads.map_independent

    def counting(calls):
        sizes.append(len(calls))
        return real(calls)

    import factors.host_points as host_points  # noqa: PLC0415
    import factors.smart as smart  # noqa: PLC0415

    monkeypatch.setattr(host_points, "map_independent", counting)
    monkeypatch.setattr(smart, "map_independent", counting)
    results = []
    for threads in (1, 2):
        set_kernel_threads(threads)
        try:
            window = copy.deepcopy(kfs)
            res = solve_gtsam(problem(cam.left, cam.baseline, window, cfg))
        finally:
            set_kernel_threads(1)
        results.append((res, window, list(sizes)))
        sizes.clear()
    (r1, w1, s1), (r2, w2, s2) = results
    assert not s1  # one thread: each host's compiled pass (HostPoints.residuals), nothing mapped
    per_host = len(kfs)  # a host's calls: at most len(kfs) - 1 targets and its stereo term
    assert max(s2) > per_host
    assert r1.cost == r2.cost and r1.initial_cost == r2.initial_cost and r1.iterations == r2.iterations
    for a, b in zip(w1, w2):
        assert np.asarray(a.pose.matrix()).tobytes() == np.asarray(b.pose.matrix()).tobytes()
        assert a.inverse_depth.tobytes() == b.inverse_depth.tobytes() and a.affine.tobytes() == b.affine.tobytes()
    assert r1.covariances.keys() == r2.covariances.keys()
    assert all(r1.covariances[k].tobytes() == r2.covariances[k].tobytes() for k in r1.covariances)


def test_worker_threads_default_is_one_and_a_set_value_is_kept():
    base = OdometryConfig()
    assert base.window.worker_threads is None and worker_threads(base) == DEFAULT_WORKER_THREADS == 1
    asked = dataclasses.replace(base, window=dataclasses.replace(base.window, worker_threads=3))
    assert worker_threads(asked) == 3


def test_a_batch_job_asking_for_the_parallel_window_gets_one_kernel_thread_unless_it_sets_them(tmp_path):
    from gtvo.batching import _job  # noqa: PLC0415
    from gtvo.batching.spec import LogSpec  # noqa: PLC0415

    def job_config(window: dict):
        log = LogSpec(name="a", path=tmp_path / "log", config={"window": window})
        return _job(log, tmp_path / "out", None, None, 1, False, "spec.yaml: a")["config"].window

    asked = job_config({"parallel": True})
    assert asked.parallel is True and worker_threads(dataclasses.replace(OdometryConfig(), window=asked)) == 1
    assert job_config({"parallel": True, "worker_threads": 2}).worker_threads == 2


def test_a_few_rows_stay_in_the_callers_thread_and_all_points_go_to_the_kernel_threads(monkeypatch):
    import factors.host_points as host_points  # noqa: PLC0415
    from tests.test_factors_host_points import _problem  # noqa: PLC0415

    pts, poses, affines, d = _problem(n=120)
    shared: list[int] = []
    real = host_points.map_independent
    monkeypatch.setattr(host_points, "map_independent", lambda calls: shared.append(len(calls)) or real(calls))
    few = pts.residuals(poses, affines, d, rows=np.arange(host_points.MIN_ROWS_TO_SHARE - 1))
    assert shared == [] and len(few) == 3  # two targets and the stereo term, inline
    every = pts.residuals(poses, affines, d)
    assert shared == [3]
    assert all(a.residual[:len(few[0].residual)].tobytes() == b.residual.tobytes() for a, b in zip(every, few))
