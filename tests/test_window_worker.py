"""The window's worker process (gtvo/odometry/window_worker.py): how it starts (a fork of the front
end on Linux, a new interpreter elsewhere) gives the same bytes; a forked worker holds no other
worker's pipe (closing one ends it cleanly while another lives); its timeline has one span per
message, and the front end's sends and waits are recorded."""

from __future__ import annotations

import dataclasses
import os
from multiprocessing.reduction import ForkingPickler

import pytest

from gtvo.config import OdometryConfig
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.odometry import window_worker
from gtvo.odometry.window_worker import ForkedProcess, WindowWorker
from tests.test_window_port import requests


def config(parallel: bool) -> OdometryConfig:
    base = OdometryConfig()
    return dataclasses.replace(base, window=dataclasses.replace(base.window, parallel=parallel))


@pytest.fixture(scope="module")
def seq():
    return make_synthetic_sequence(n_frames=3, width=160, height=120, step_m=0.1)


def solve_two(seq, method: str, monkeypatch) -> tuple[WindowWorker, list]:
    monkeypatch.setattr(window_worker, "START_METHOD", method)
    worker = WindowWorker(seq.camera, config(True))
    first, second = requests(seq)
    worker.join(first, optimize=False)
    worker.join(second, optimize=True)
    return worker, worker.due(now=True)


@pytest.mark.slow
def test_a_forked_and_a_spawned_worker_give_the_same_bytes(seq, monkeypatch):
    if window_worker.START_METHOD != "fork":
        pytest.skip("os.fork is used on Linux only")
    out = {}
    for method in ("fork", "spawn"):
        worker, updates = solve_two(seq, method, monkeypatch)
        try:
            assert isinstance(worker._process, ForkedProcess) == (method == "fork")
            (update,) = updates
            out[method] = [(m.pose.matrix().tobytes(), m.inverse_depth.tobytes()) for m in update.members]
            out[method].append(update.result.cost)
        finally:
            worker.close()
        assert worker._process.poll() == 0  # ended at its pipe's close, not killed
    assert out["fork"] == out["spawn"]


@pytest.mark.slow
def test_closing_one_forked_worker_ends_it_while_another_lives(seq, monkeypatch):
    """The second worker, forked while the first one's pipe is open here, closed its copy of it: the
    first sees its pipe close and exits 0 (had the second kept it, the first would wait on, and be
    killed after ``_stop``'s timeout: a negative exit code)."""
    monkeypatch.setattr(window_worker, "START_METHOD", "fork" if window_worker.START_METHOD == "fork" else "spawn")
    first = WindowWorker(seq.camera, config(True))
    second = WindowWorker(seq.camera, config(True))
    try:
        first.close()
        assert first._process.poll() == 0
        assert second._process.poll() is None  # still serving
        a, b = requests(seq)
        second.join(a, optimize=False)
        second.join(b, optimize=True)
        assert len(second.due(now=True)) == 1
    finally:
        second.close()
    assert second._process.poll() == 0


@pytest.mark.slow
def test_the_timeline_has_the_start_and_one_span_per_message_and_the_front_ends_events(seq, monkeypatch):
    worker, _ = solve_two(seq, window_worker.START_METHOD, monkeypatch)
    try:
        spans = worker.timeline()
    finally:
        worker.close()
    assert [s.kind for s in spans] == ["start", "join", "join"]
    assert all(s.wall_end >= s.wall_start and s.cpu_seconds >= 0 for s in spans)
    sends = [e.number for e in worker.events if e.kind == "send"]
    waits = [e.number for e in worker.events if e.kind == "wait"]
    assert sends == [0, 1, 2] and waits == [0, 1, 2]  # the joins' replies in order, then the timeline's
    assert all(e.wall_end >= e.wall_start and e.cpu_seconds >= 0 for e in worker.events)
    # the pickled sizes: a join (its points) outweighs the question for the timeline, whose reply is
    # the spans as they were pickled back, byte for byte
    sent = [e.nbytes for e in worker.events if e.kind == "send"]
    assert sent[0] > 1000 and sent[2] < sent[0]
    assert [e for e in worker.events if e.kind == "wait"][-1].nbytes == len(ForkingPickler.dumps(("ok", spans)))


def test_a_forked_process_handle_reports_its_exit_code():
    if window_worker.START_METHOD != "fork":
        pytest.skip("os.fork is used on Linux only")
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        os._exit(3)
    handle = ForkedProcess(pid)
    assert handle.wait(timeout=30) == 3 and handle.poll() == 3
    handle.kill()  # ended: nothing to do
