"""BLAS limited to one thread while the odometry works (threadpoolctl)."""

from __future__ import annotations

_BLAS_CONTROLLER = None


def single_threaded_blas():
    """A context that limits BLAS to one thread (the controller is built once: it scans libraries).

    The tracker's and the window's many small matrix products were up to 300x slower
    multithreaded on a busy 2-core machine."""
    global _BLAS_CONTROLLER
    if _BLAS_CONTROLLER is None:
        from threadpoolctl import ThreadpoolController  # noqa: PLC0415

        _BLAS_CONTROLLER = ThreadpoolController()
    return _BLAS_CONTROLLER.limit(limits=1, user_api="blas")
