"""factors._compiled_rows: the safeguard's row copies between pass buffers equal numpy's gather and scatter."""

from __future__ import annotations

import numpy as np

from factors._compiled_rows import copy_rows


def test_copy_rows_equals_numpy_fancy_assignment():
    """``copy_rows`` writes exactly ``dst[:, rows] = src[:, other_rows]`` (float and bool arrays, rows
    in any order) and nothing else; no rows copies nothing."""
    rng = np.random.default_rng(0)
    rows = np.array([7, 2, 11, 0], dtype=np.intp)
    other = np.array([1, 3, 0, 5], dtype=np.intp)
    for src in (rng.normal(size=(3, 6, 10)), rng.random((3, 6, 10)) < 0.5):
        dst = np.zeros((3, 12, 10), dtype=src.dtype)
        expected = dst.copy()
        expected[:, rows] = src[:, other]
        copy_rows(dst, rows, src, other)
        assert dst.tobytes() == expected.tobytes()
        copy_rows(dst, rows[:0], src, other[:0])
        assert dst.tobytes() == expected.tobytes()
