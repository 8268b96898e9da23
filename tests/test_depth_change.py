"""The tracked-translation scale after a keyframe's depths change (gtvo.window.depth_change)."""

from __future__ import annotations

import numpy as np
import pytest

from gtvo.errors import InputError
from gtvo.window.depth_change import MIN_SCALE_POINTS, tracked_translation_scale


def test_uniform_depth_scale_is_recovered_exactly():
    rho = np.random.default_rng(0).uniform(0.02, 0.5, 200)
    assert tracked_translation_scale(rho, rho / 1.15) == pytest.approx(1.15, rel=1e-12)
    assert tracked_translation_scale(rho, rho) == pytest.approx(1.0, rel=1e-12)


def test_a_disparity_offset_keeps_the_flow_in_least_squares():
    """A constant disparity change (a rig offset of 2 px at fx b = 100): the factor is the one whose
    translational flow rho_new s t matches the old rho_old t best, between the near and far points' ratios."""
    rng = np.random.default_rng(1)
    disparity = rng.uniform(5.0, 40.0, 300)
    old, new = (disparity - 2.0) / 100.0, disparity / 100.0
    s = tracked_translation_scale(old, new)
    ratios = old / new
    assert ratios.min() < s < ratios.max()
    grid = np.linspace(ratios.min(), ratios.max(), 2001)
    best = grid[np.argmin([np.sum((new * g - old) ** 2) for g in grid])]
    assert s == pytest.approx(best, abs=1e-3)


def test_too_few_points_or_mismatched_inputs():
    rho = np.full(MIN_SCALE_POINTS - 1, 0.1)
    assert tracked_translation_scale(rho, rho / 2) == 1.0
    old = np.r_[np.full(MIN_SCALE_POINTS, 0.1), 0.0, np.nan]
    assert tracked_translation_scale(old, np.r_[np.full(MIN_SCALE_POINTS, 0.05), 0.3, 0.3]) == pytest.approx(2.0)
    with pytest.raises(InputError, match="must match"):
        tracked_translation_scale(np.ones(12), np.ones(11))
