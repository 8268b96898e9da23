"""The compiled loops' thread pool (gtvo/core/threads.py) and the window's use of it: results in
order, exceptions raised in the caller, and a window optimisation that does not depend on the
number of threads, bit for bit."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from gtvo.core import threads
from gtvo.errors import InputError


@pytest.fixture(autouse=True)
def _restore():
    before = threads.threads()
    yield
    threads.set_threads(before)


def test_thread_map_keeps_the_order_and_uses_the_pool():
    threads.set_threads(2)
    names = []

    def work(x):
        names.append(threading.current_thread().name)
        return x * x

    assert threads.thread_map(work, range(20)) == [x * x for x in range(20)]
    assert any(n.startswith("gtvo") for n in names)
    threads.set_threads(1)
    names.clear()
    assert threads.thread_map(work, [3, 4]) == [9, 16]
    assert all(not n.startswith("gtvo") for n in names)


def test_an_exception_in_a_call_reaches_the_caller():
    threads.set_threads(2)

    def work(x):
        if x == 3:
            raise InputError("bad item 3")
        return x

    with pytest.raises(InputError, match="bad item 3"):
        threads.thread_map(work, range(6))


@pytest.mark.parametrize("bad", [-1, 1.5, True, "2"])
def test_a_bad_thread_count_is_refused(bad):
    with pytest.raises(InputError, match="threads"):
        threads.set_threads(bad)


def test_zero_means_the_cores_of_the_process():
    threads.set_threads(0)
    assert threads.threads() == threads.default_threads() >= 1


def test_the_window_does_not_depend_on_the_thread_count():
    from gtvo.config import OdometryConfig  # noqa: PLC0415
    from gtvo.datasets.synthetic import make_synthetic_sequence  # noqa: PLC0415
    from gtvo.odometry import VisualOdometry  # noqa: PLC0415
    from gtvo.window import WindowConfig  # noqa: PLC0415

    seq = make_synthetic_sequence(n_frames=14, step_m=0.3, noise_sigma=1.0)
    runs = []
    for n in (1, 2):
        vo = VisualOdometry(seq.camera, OdometryConfig(mode="window", window=WindowConfig(threads=n, covariances=False)))
        assert threads.threads() == n
        for frame in seq:
            vo.process(frame)
        vo.finish()
        assert len(vo.window_results) >= 2
        runs.append(np.stack([e.T_world_cam for e in vo.estimates]))
    assert np.array_equal(runs[0], runs[1])
