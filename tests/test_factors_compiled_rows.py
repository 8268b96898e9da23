"""factors._compiled_rows: the safeguard's row copies (between pass buffers, and put_rows') equal numpy's gather and scatter."""

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


def test_put_rows_copies_exactly_the_rows_numpy_assignment_does():
    """``factors.photometric.put_rows`` (one compiled copy per array for indices in range) writes
    what ``a[rows] = b[other_rows]`` writes in every array, with and without ``other_rows``, and
    refuses rows out of range as numpy does."""
    import dataclasses

    import pytest

    from factors.photometric import PhotometricLinearization, put_rows

    rng = np.random.default_rng(1)

    def lin(n: int) -> PhotometricLinearization:
        return PhotometricLinearization(rng.normal(size=(n, 8)), rng.random((n, 8)) < 0.7, rng.normal(size=(n, 8)),
                                        rng.normal(size=(n, 8, 6)), None, rng.normal(size=(n, 8, 2)), None,
                                        rng.normal(size=(n, 8, 2)), 0, 0, 0, J_offset=rng.normal(size=(n, 8, 2)))

    a, b = lin(20), lin(6)
    names = ("residual", "valid", "J_depth", "J_host", "J_affine_host", "uv_target", "J_offset")
    rows = np.array([3, 19, 0, 8])
    for source, src_rows, take in ((b, np.array([5, 0, 2, 1]), np.array([5, 0, 2, 1])), (lin(4), None, slice(None))):
        merged = put_rows(dataclasses.replace(a, **{f: getattr(a, f).copy() for f in names}), rows, source, src_rows)
        for name in names:
            expected = getattr(a, name).copy()
            expected[rows] = getattr(source, name)[take]
            assert getattr(merged, name).tobytes() == expected.tobytes(), name
    with pytest.raises(IndexError):
        put_rows(a, np.array([20]), b, np.array([0]))
