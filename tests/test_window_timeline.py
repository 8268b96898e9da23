"""benchmarks/window_timeline.py: the replay of a parallel run's schedule on two idle cores, on a
hand-made timeline whose answer is worked out by hand."""

from __future__ import annotations

import pytest

from benchmarks.window_timeline import replay
from gtvo.odometry.window_worker import FrontEndEvent, MessageSpan


def two_joins() -> dict:
    """The front end sends at 0.1 and 0.2 s of its CPU, waits for both replies at 0.2 and 0.3, ends
    at 1.0; the worker (no start cost) takes 0.5 s per join."""
    return {"cpu0": 0.0, "cpu1": 1.0, "started": (0.0, 0.0), "stages": {},
            "spans": [MessageSpan("start", 0, 0, 0.0), MessageSpan("join", 0, 0, 0.5), MessageSpan("join", 0, 0, 0.5)],
            "events": [FrontEndEvent("send", 0, 0, 0, 0.1), FrontEndEvent("send", 1, 0, 0, 0.2),
                       FrontEndEvent("wait", 0, 0, 0, 0.2), FrontEndEvent("wait", 1, 0, 0, 0.3)]}


def test_the_replay_waits_for_the_worker_and_counts_its_idles():
    # join 0: 0.1-0.6 (idle 0.1 before), the front end waits 0.4 at 0.2; join 1: 0.6-1.1, the front
    # end, at 0.7, waits 0.4; then its last 0.7 s: 1.8 s in all
    out = replay(two_joins())
    assert out["seconds"] == pytest.approx(1.8) and out["waits"] == pytest.approx(0.8)
    assert out["idle"] == pytest.approx(0.1)


def test_a_cheaper_window_shortens_the_replay_and_a_sequential_run_is_its_cpu():
    out = replay(two_joins(), scale=0.5)  # joins of 0.25 s: waits of 0.15 twice
    assert out["seconds"] == pytest.approx(1.3) and out["waits"] == pytest.approx(0.3)
    sequential = {"cpu0": 0.0, "cpu1": 2.0, "spans": None, "events": [], "started": None,
                  "stages": {"linearisation": 1.0}}
    assert replay(sequential)["seconds"] == pytest.approx(2.0)
    assert replay(sequential, scale=0.5)["seconds"] == pytest.approx(1.5)  # its window stages halved


def test_contention_slows_both_processes_once_the_worker_is_asked_for():
    # every CPU second after the start at 1.1: the whole replay of two_joins at 1.1x (1.8 -> 1.98)
    out = replay(two_joins(), contention=0.1)
    assert out["seconds"] == pytest.approx(1.98) and out["waits"] == pytest.approx(0.88)
    assert out["idle"] == pytest.approx(0.11)
    # asked for at 0.1 s of the front end's CPU: its first 0.1 s at full speed (1.8 * 1.1 - 0.01)
    late = two_joins()
    late["started"] = (0.0, 0.1)
    assert replay(late, contention=0.1)["seconds"] == pytest.approx(1.97)
    sequential = {"cpu0": 0.0, "cpu1": 2.0, "spans": None, "events": [], "started": None, "stages": {}}
    assert replay(sequential, contention=0.1)["seconds"] == pytest.approx(2.0)  # one process: nothing beside it
