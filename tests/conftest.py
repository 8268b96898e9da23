"""Shared fixtures: where the real data lives, and skipping when it is absent."""

from __future__ import annotations

import os

# Single-threaded BLAS, as the gtvo CLI runs (gtvo/cli.py): the window's many small products are
# far slower multithreaded on a busy 2-core machine. Set before numpy is first imported.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
import signal
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _sigint_handler_restored():
    """Each test leaves SIGINT's handler as it found it: a command run in-process ignores SIGINT
    once its outputs are in place (``gtvo.core.interrupt.outputs_in_place``, as the CLI does before
    it exits), which would otherwise turn a later test's Ctrl-C into nothing."""
    handler = signal.getsignal(signal.SIGINT)
    yield
    if signal.getsignal(signal.SIGINT) is not handler and handler is not None:
        signal.signal(signal.SIGINT, handler)


def shared_data_dir() -> Path:
    """``$GTVO_SHARED_DATA`` or ``../shared/data`` beside the checkout."""
    env = os.environ.get("GTVO_SHARED_DATA")
    return Path(env) if env else REPO_ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real-data folder; tests that use it are skipped when it is absent."""
    d = shared_data_dir()
    if not d.is_dir():
        pytest.skip(f"real data not found at {d}")
    return d


@pytest.fixture(scope="session")
def kitti_snippet(shared_data):
    """A function that opens KITTI_sequence_1 (``gtvo.open_sequence``'s keywords, e.g.
    ``max_frames``), the test skipped when the snippet is absent."""
    from gtvo.datasets import open_sequence  # noqa: PLC0415

    folder = shared_data / "kitti_stereo_sample" / "KITTI_sequence_1"

    def open_snippet(**options):
        if not folder.is_dir():
            pytest.skip(f"KITTI snippet not found at {folder}")
        return open_sequence(folder, **options)

    return open_snippet


@pytest.fixture(scope="session")
def open3d():
    """The open3d module; tests that need it are skipped, with the reason, when it cannot be
    imported (its wheel needs the system library libusb-1.0)."""
    from gtvo.core.optional import require_open3d
    from gtvo.errors import DependencyError

    try:
        return require_open3d()
    except DependencyError as exc:
        pytest.skip(str(exc))
