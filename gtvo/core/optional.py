"""Lazy imports of optional heavy dependencies (open3d; rerun-sdk, the ``viewer`` extra).

Open3D's wheel needs the system library libusb-1.0 (``apt-get install libusb-1.0-0``);
without it ``import open3d`` fails. gtvo imports open3d only where it is used, so
everything else keeps working and the user gets one line naming what is missing.
"""

from __future__ import annotations

from types import ModuleType

from gtvo.errors import DependencyError, caused_by_interrupt


def require_open3d() -> ModuleType:
    """Import and return ``open3d``, or raise :class:`DependencyError` with a one-line reason."""
    try:
        import open3d  # noqa: PLC0415
    except ImportError as exc:  # pragma: no cover - depends on the machine
        if caused_by_interrupt(exc):  # Ctrl-C during the import: not a missing package
            raise KeyboardInterrupt from exc
        msg = str(exc)
        if "libusb" in msg:
            raise DependencyError(
                "open3d needs the system library libusb-1.0 (install it: apt-get install libusb-1.0-0)"
            ) from exc
        raise DependencyError(f"open3d is not importable ({msg}); install it: pip install open3d") from exc
    return open3d


def require_rerun() -> ModuleType:
    """Import and return ``rerun`` (the ``rerun-sdk`` package, the ``viewer`` extra), or raise
    :class:`DependencyError` with a one-line reason naming the extra."""
    try:
        import rerun  # noqa: PLC0415
    except ImportError as exc:  # pragma: no cover - depends on the machine
        raise DependencyError(f'the Rerun viewer output needs rerun-sdk ({exc.msg}): pip install "gtvo[viewer]"') \
            from exc
    return rerun
