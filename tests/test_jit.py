"""gtvo.core.jit: the first run's announcement of the kernels it compiles."""

from __future__ import annotations

import io

import numba

from gtvo.core import jit


def _uncached_kernels(n: int) -> list:
    """``n`` kernels without a disk cache (numba's cache=False: as with no writable cache folder)."""
    return [numba.njit(cache=False)(lambda x: x + 1) for _ in range(n)]


def test_every_kernel_of_gtvo_is_registered():
    import factors._compiled  # noqa: F401
    import gtvo.frontend._compiled  # noqa: F401

    names = {k.py_func.__name__ for k in jit.KERNELS}
    assert {"warp_residuals", "pick_cells", "zssd_costs"} <= names


def test_no_announcement_when_few_kernels_compile(monkeypatch):
    monkeypatch.setattr(jit, "KERNELS", _uncached_kernels(jit.MIN_ANNOUNCED - 1))
    out = io.StringIO()
    assert jit.announce_compilation(out) == jit.MIN_ANNOUNCED - 1
    assert out.getvalue() == ""


def test_announcement_and_count_of_compiled_kernels(monkeypatch):
    kernels = _uncached_kernels(jit.MIN_ANNOUNCED)
    monkeypatch.setattr(jit, "KERNELS", kernels)
    assert not any(jit.has_cached_code(k) for k in kernels)
    assert jit.cache_folder(kernels[0]) is None
    out = io.StringIO()
    assert jit.announce_compilation(out) == len(kernels)
    first = out.getvalue().splitlines()
    assert len(first) == 1
    assert f"compiling {len(kernels)} of {len(kernels)} compiled kernels" in first[0]
    assert f"about {len(kernels) * jit.COMPILE_SECONDS_PER_KERNEL:.0f} s" in first[0]
    assert "no writable cache folder" in first[0] and "NUMBA_CACHE_DIR" in first[0]
    for k in kernels:
        assert k(1) == 2
    lines = out.getvalue().splitlines()
    assert lines[-1].startswith(f"gtvo: compiled {len(kernels)}/{len(kernels)} kernels")
    kernels2 = _uncached_kernels(1)
    kernels2[0](1)  # the counter unregistered itself after the last: nothing more is printed
    assert out.getvalue().splitlines() == lines
