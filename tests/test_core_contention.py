"""benchmarks/core_contention.py: the arithmetic of its figures (the on/off pairs of ``--toggle``
and the busy/idle fit of the sampled windows) on hand-made samples whose answer is worked out by hand."""

from __future__ import annotations

import pytest

from benchmarks.core_contention import busy_ratio, on_off_ratios


def test_each_on_half_is_compared_with_the_off_halves_around_it():
    # (half, repetitions, CPU s): off halves cost 1.0 then 3.0 per repetition around an on half of 2.4;
    # half 4 has no repetition and half 0 no left neighbour: one pair only
    halves = [(0, 10, 10.0), (1, 10, 10.0), (2, 10, 24.0), (3, 5, 15.0), (4, 0, 0.0), (5, 10, 10.0)]
    ratios, off = on_off_ratios(halves)
    assert ratios == [pytest.approx(2.4 / 2.0)]
    assert off == [pytest.approx(1.0), pytest.approx(3.0), pytest.approx(1.0)]


def test_a_drift_that_is_not_the_other_core_cancels_in_the_pairs():
    # the machine slows by 1 % every half, the other core changes nothing: every pair says 1.0
    halves = [(h, 100, 100 * 1.01 ** h) for h in range(9)]
    ratios, _ = on_off_ratios(halves)
    assert len(ratios) == 3 and ratios == pytest.approx([2 / (1.01 + 1 / 1.01)] * 3)  # halves 2, 4, 6: 0.99995


def test_the_busy_fit_needs_both_ends_and_reads_the_line_at_one_over_zero():
    assert busy_ratio([(0.9, 2.0)] * 10).startswith("n/a (10/0)")  # the other core never idle: no contrast
    samples = [(0.0, 1.0)] * 5 + [(0.5, 1.1)] * 5 + [(1.0, 1.2)] * 5  # cost = 1 + 0.2 x
    assert busy_ratio(samples) == "1.20; 1.20 (5/5)"
