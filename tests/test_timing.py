"""The per-stage clock (gtvo/core/timing.py) and where it shows: VisualOdometry.clock,
report.json's seconds_by_stage, benchmarks/frame_budget.py."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gtvo.core import timing
from gtvo.core.timing import FRAME_STAGES, StageClock, active_clock, per_frame_ms, stage, timed


class FakeTimer:
    """A clock that moves only when told: exact, deterministic stage times."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now

    def spend(self, seconds: float) -> None:
        self.now += seconds


def test_nested_stages_take_their_time_out_of_the_outer_one() -> None:
    t = FakeTimer()
    clock = StageClock(timer=t)
    with clock.activate("other"):
        t.spend(1.0)
        with stage("solve"):
            t.spend(2.0)
            with stage("linearisation"):
                t.spend(3.0)
            t.spend(0.5)
        t.spend(0.25)
    s = clock.seconds
    assert s["linearisation"] == 3.0
    assert s["solve"] == 2.5  # its own time, not the nested 3.0
    assert s["other"] == 1.25
    assert clock.total() == 6.75  # every interval charged once: the whole span
    assert clock.entries["solve"] == 1 and clock.entries["linearisation"] == 1 and clock.entries["other"] == 1
    assert set(s) == set(FRAME_STAGES) and s["tracking"] == 0.0


class TickingTimer:
    """A clock that moves by one tick at every reading: the span a clock covers is known exactly,
    whatever the machine's load (no wall-clock comparison)."""

    def __init__(self, tick: float = 1.0) -> None:
        self.now = 0.0
        self.tick = tick
        self.reads: list[float] = []

    def __call__(self) -> float:
        self.now += self.tick
        self.reads.append(self.now)
        return self.now


def test_stages_add_up_to_the_span_from_the_first_reading_to_the_last() -> None:
    t = TickingTimer(tick=0.001)
    clock = StageClock(timer=t)
    with clock.activate("other"):
        for _ in range(50):
            with stage("solve"):
                with stage("linearisation"):
                    pass
    # every interval between two readings is charged to exactly one stage: nothing lost, nothing twice
    assert len(t.reads) == 1 + 50 * 4 + 1
    assert clock.total() == pytest.approx(t.reads[-1] - t.reads[0], rel=1e-12)
    assert clock.entries["solve"] == 50 and clock.entries["linearisation"] == 50
    assert clock.seconds["linearisation"] == pytest.approx(50 * 0.001)  # enter -> leave: one tick each
    assert clock.seconds["solve"] == pytest.approx(50 * 2 * 0.001)  # its own ticks around the nested stage
    assert clock.seconds["other"] == pytest.approx(51 * 0.001)  # before each solve, and after the last


def test_an_absorbing_stage_keeps_the_stages_opened_inside_it() -> None:
    t = FakeTimer()
    clock = StageClock(timer=t)
    with clock.activate("other"):
        with stage("covariances", absorb=True):
            with stage("linearisation"):
                t.spend(2.0)
            with stage("window_build"):
                t.spend(1.0)
        with stage("linearisation"):  # after the absorbing stage closed: counted again
            t.spend(0.5)
    assert clock.seconds["covariances"] == 3.0
    assert clock.seconds["linearisation"] == 0.5
    assert clock.entries["linearisation"] == 1 and clock.entries["window_build"] == 0
    assert clock.seconds["window_build"] == 0.0 and clock.seconds["other"] == 0.0


def test_same_stage_nested_in_itself_is_entered_once() -> None:
    t = FakeTimer()
    clock = StageClock(timer=t)
    with clock.activate():
        with stage("linearisation"):
            t.spend(1.0)
            with stage("linearisation"):
                t.spend(2.0)
            t.spend(1.0)
    assert clock.seconds["linearisation"] == 4.0 and clock.total() == 4.0
    assert clock.entries["linearisation"] == 1  # entered once: the call inside it is part of it


def test_unknown_stage_is_refused_by_a_clock_with_fixed_stages_and_added_by_an_open_one() -> None:
    clock = StageClock()
    with clock.activate():
        with pytest.raises(ValueError, match="unknown stage 'linearization'.*linearisation"):
            with stage("linearization"):
                pass
    open_clock = StageClock(stages=None)
    with open_clock.activate("loop"):
        with stage("anything"):
            pass
    assert set(open_clock.seconds) == {"loop", "anything"}


def test_a_stage_left_by_an_exception_is_closed() -> None:
    clock = StageClock()

    @timed("solve")
    def fails() -> None:
        raise RuntimeError("boom")

    with clock.activate("other"):
        with pytest.raises(RuntimeError):
            fails()
        with pytest.raises(KeyError):
            with stage("tracking"):
                raise KeyError("x")
    assert clock._stack == []  # noqa: SLF001  nothing left open
    clock.reset()
    assert clock.total() == 0.0 and sum(clock.entries.values()) == 0


def test_without_an_active_clock_hooks_do_nothing_and_cost_little() -> None:
    assert active_clock() is None
    calls = []

    @timed("linearisation")
    def f(x: int) -> int:
        calls.append(x)
        return 2 * x

    with stage("solve"):  # no clock: a no-op context
        assert f(3) == 6
    assert calls == [3] and f.__name__ == "f" and f.__wrapped__ is not None  # type: ignore[attr-defined]
    # the inactive decorator's cost is a ContextVar lookup and the call: counted as Python calls made
    # (the wrapper and f, nothing else), not timed, so that a busy machine cannot fail it
    import sys

    events: list[str] = []

    def count(frame, event, arg):
        if event == "call":
            events.append(frame.f_code.co_name)

    sys.setprofile(count)
    try:
        f(1)
        with stage("solve"):
            pass
    finally:
        sys.setprofile(None)
    assert events[:2] == ["wrapper", "f"]
    assert [e for e in events[2:] if e not in ("stage", "__enter__", "__exit__")] == []
    assert events.count("stage") == 1 and events.count("__enter__") == 1  # no clock: the shared no-op context


def test_activate_nests_and_restores_the_clock_before() -> None:
    t = FakeTimer()
    a, b = StageClock(timer=t), StageClock(timer=t)
    with a.activate("other"):
        with b.activate("other"):
            assert active_clock() is b
            with stage("tracking"):
                t.spend(1.0)
        assert active_clock() is a
    assert active_clock() is None
    assert b.seconds["tracking"] == 1.0 and a.seconds["tracking"] == 0.0


def test_snapshot_includes_the_open_stage_and_reset_refuses_while_open() -> None:
    t = FakeTimer()
    clock = StageClock(timer=t)
    with clock.activate("other"):
        t.spend(1.5)
        assert clock.snapshot()["other"] == 1.5 and clock.seconds["other"] == 0.0
        with pytest.raises(RuntimeError, match="stages open"):
            clock.reset()


def test_per_frame_ms() -> None:
    assert per_frame_ms({"a": 0.5, "b": 0.0}, 10) == {"a": 50.0, "b": 0.0}
    with pytest.raises(ValueError):
        per_frame_ms({"a": 1.0}, 0)


# --- the odometry's clock ----------------------------------------------------------------------

@pytest.fixture(scope="module")
def short_sequence():
    from gtvo.datasets.synthetic import make_synthetic_sequence

    return make_synthetic_sequence(n_frames=10, width=240, height=180, step_m=0.1)


def _config(mode: str = "window", solver: str | None = None):
    """Every frame a keyframe and a window of 3: ten frames build, solve and marginalise."""
    import dataclasses

    from gtvo.config import KeyframeConfig, OdometryConfig, SolverConfig

    config = OdometryConfig(mode=mode, keyframes=KeyframeConfig(max_motion=1e-4),
                            **({} if solver is None else {"solver": SolverConfig.both(solver)}))
    return dataclasses.replace(config, window=dataclasses.replace(config.window, size=3))


def _run(seq, mode: str, clock: bool = True):
    from gtvo.odometry import VisualOdometry

    vo = VisualOdometry(seq.camera, _config(mode))
    if not clock:
        vo.clock = None
    for i in range(len(seq)):
        vo.process(seq.frame(i))
    return vo


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["gtsam", "handrolled"])
def test_window_run_stages_add_up_to_the_frames_time(short_sequence, solver: str) -> None:
    """Every interval of every frame's processing is charged to one stage: with a clock that ticks
    at each reading, the stages sum exactly to the frames' spans (no wall-clock comparison)."""
    from gtvo.odometry import VisualOdometry

    vo = VisualOdometry(short_sequence.camera, _config(solver=solver))
    ticks = TickingTimer(tick=1e-3)
    vo.clock = StageClock(timer=ticks)
    spans = 0.0
    for i in range(len(short_sequence)):
        frame = short_sequence.frame(i)
        first = len(ticks.reads)
        vo.process(frame)
        read = ticks.reads[first:]
        assert len(read) >= 2
        spans += read[-1] - read[0]
    s = vo.clock.snapshot()
    assert len(vo.window_results) >= 2 and vo.window is not None and vo.window.optimizer.n_removed >= 1
    for name in ("tracking", "point_selection", "stereo_search", "keyframe_setup", "window_build", "linearisation",
                 "solve", "marginalisation", "covariances", "other"):
        assert s[name] > 0, name
    assert s["reading"] == 0.0 and s["outputs"] == 0.0  # the pipeline's, not the odometry's
    assert sum(s.values()) == pytest.approx(spans, rel=1e-9)
    # every window optimisation went through the window's stages
    assert vo.clock.entries["window_build"] >= len(vo.window_results)
    assert vo.clock.entries["solve"] >= len(vo.window_results)


def test_track_mode_has_no_window_stages_and_the_clock_can_be_off(short_sequence) -> None:
    vo = _run(short_sequence, "track")
    s = vo.clock.snapshot()
    assert s["tracking"] > 0 and s["point_selection"] > 0
    for name in ("window_build", "linearisation", "solve", "marginalisation", "covariances"):
        assert s[name] == 0.0, name
    off = _run(short_sequence, "track", clock=False)
    assert off.clock is None and timing.active_clock() is None
    np.testing.assert_array_equal(off.trajectory().poses, vo.trajectory().poses)  # timing changes nothing


def test_report_json_has_the_stages(short_sequence, tmp_path) -> None:
    import gtvo

    rep = gtvo.run(short_sequence, out=tmp_path / "out")
    on_disk = json.loads((tmp_path / "out" / "report.json").read_text())
    for report in (rep, on_disk):
        s, ms = report["seconds_by_stage"], report["ms_per_frame_by_stage"]
        assert list(s) == list(FRAME_STAGES) and list(ms) == list(FRAME_STAGES)
        assert s["reading"] > 0 and s["outputs"] > 0 and s["linearisation"] > 0
        assert ms["tracking"] == pytest.approx(1000.0 * s["tracking"] / report["frames"])
        # the frames' loop is every stage but the outputs (written after it)
        assert sum(s.values()) - s["outputs"] == pytest.approx(report["seconds"], rel=0.02)


# --- the benchmark -------------------------------------------------------------------------------

def test_linear_fit_tells_a_line_from_a_curve() -> None:
    from benchmarks.frame_budget import linear_fit

    x = [300.0, 600.0, 1200.0, 2000.0]
    line = linear_fit(x, [5.0 + 0.02 * v for v in x])
    assert line["per_100_points"] == pytest.approx(2.0) and line["intercept"] == pytest.approx(5.0)
    assert line["max_rel_residual"] < 1e-9 and line["r2"] == pytest.approx(1.0)
    curve = linear_fit(x, [5.0 + 1e-5 * v * v for v in x])
    assert curve["max_rel_residual"] > 0.1 and curve["r2"] < 0.999


@pytest.mark.slow
def test_frame_budget_script_smoke(shared_data, tmp_path, capsys) -> None:
    from benchmarks.frame_budget import main

    seq = shared_data / "kitti_stereo_sample" / "KITTI_sequence_1"
    if not seq.is_dir():
        pytest.skip(f"{seq} is absent")
    assert main(["--sequence", str(seq), "--max-frames", "4", "--json", str(tmp_path / "b.json")]) == 0
    out = capsys.readouterr().out
    assert "| linearisation |" in out and "x ref" in out and "frames/s" in out and "frames by kind" in out
    data = json.loads((tmp_path / "b.json").read_text())
    b = data["budget"]
    assert sum(b["stage_ms"].values()) == pytest.approx(b["frame_ms"], rel=0.05)
    assert sum(n for n, _ in b["frame_kinds_ms"].values()) == 4
    assert main(["--sequence", str(tmp_path / "nothing")]) == 2
    assert main(["--sequence", str(seq), "--points", "300,600"]) == 2  # a line needs 3 budgets
    assert main(["--sequence", str(seq), "--json", str(tmp_path / "no" / "b.json")]) == 2


def test_memory_slope_is_over_the_second_half() -> None:
    from benchmarks.memory_vo import second_half_slope

    # grows 10 MiB per 100 frames in the first half, flat in the second
    samples = [(f, 500.0 + 0.1 * min(f, 500)) for f in range(50, 1001, 50)]
    assert second_half_slope(samples) == pytest.approx(0.0, abs=1e-9)
    assert second_half_slope([(f, 0.02 * f) for f in range(50, 1001, 50)]) == pytest.approx(2.0)
    assert second_half_slope([(50, 1.0)]) is None and second_half_slope([]) is None
