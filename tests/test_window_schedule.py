"""When the window is optimised and where it runs (gtvo/odometry/window_schedule.py): with
``window.parallel: auto`` the schedule moves the window to a worker once, at a fixed keyframe, when
the keyframes so far would have overlapped the front end; a count over the sequence, not a clock."""

from __future__ import annotations

import dataclasses

import pytest

from factors.params import PhotometricConfig
from gtvo.core.camera import PinholeCamera
from gtvo.odometry.window_schedule import (
    AUTO_DECISION_KEYFRAME,
    AUTO_MIN_OVERLAP,
    WindowSchedule,
)
from gtvo.window import WindowConfig


def schedule(parallel) -> WindowSchedule:
    return WindowSchedule(dataclasses.replace(WindowConfig(), parallel=parallel), PhotometricConfig(),
                          PinholeCamera(100.0, 100.0, 50.0, 40.0, 100, 80))


def decisions(parallel, overlaps: list[bool]) -> list[int]:
    """The keyframes (counted from 1) at which the schedule moves the window to a worker."""
    s = schedule(parallel)
    moved = []
    for overlap in overlaps:
        s.note_keyframe(overlap)
        if s.moves_to_worker():
            moved.append(s.keyframes)
    return moved


def test_the_sequential_order_is_the_default():
    assert WindowConfig().parallel is False


def test_keyframes_at_every_frame_move_the_window_to_the_worker_once_at_the_decision_keyframe():
    every_frame = [False] + [True] * 40  # the first keyframe has none before it
    assert decisions("auto", every_frame) == [AUTO_DECISION_KEYFRAME]


def test_a_log_where_nothing_overlaps_stays_in_this_process():
    assert decisions("auto", [False] * 40) == []
    # below the fraction at the decision: stays, whatever comes after
    needed = int(AUTO_MIN_OVERLAP * (AUTO_DECISION_KEYFRAME - 1) + 0.999)
    few = [False] + [True] * (needed - 1) + [False] * (AUTO_DECISION_KEYFRAME - needed) + [True] * 30
    assert decisions("auto", few) == []
    just = [False] + [True] * needed + [False] * 40
    assert decisions("auto", just) == [AUTO_DECISION_KEYFRAME]


def test_a_short_run_and_the_forced_settings_never_move_the_window():
    assert decisions("auto", [False] + [True] * (AUTO_DECISION_KEYFRAME - 2)) == []
    assert decisions(True, [False] + [True] * 40) == []  # in a worker from the start
    assert decisions(False, [False] + [True] * 40) == []  # --no-parallel: the sequential order


def test_the_fixed_lag_back_end_stays_where_it_started():
    """Its iSAM2 smoother cannot move between processes: ``auto`` keeps it in this one."""
    s = WindowSchedule(WindowConfig(parallel="auto", backend="fixed_lag"), PhotometricConfig(),
                       PinholeCamera(100.0, 100.0, 50.0, 40.0, 100, 80))
    for overlap in [False] + [True] * 30:
        s.note_keyframe(overlap)
        assert not s.moves_to_worker()


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_parallel_takes_true_false_or_auto(value):
    from gtvo.core.settings import SettingError

    with pytest.raises(SettingError, match="must be true, false or 'auto'"):
        WindowConfig(parallel=value)
