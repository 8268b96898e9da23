"""open3d is imported lazily: its absence costs only the point-cloud features, with one line."""

import builtins
import json
import sys

import pytest

from gtvo.core.optional import require_open3d
from gtvo.errors import DependencyError


@pytest.fixture
def open3d_missing_libusb(monkeypatch):
    real_import = builtins.__import__

    def fake_import(name, *args, **kwargs):
        if name == "open3d" or name.startswith("open3d."):
            raise ImportError("libusb-1.0.so.0: cannot open shared object file: No such file or directory")
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "open3d", raising=False)
    monkeypatch.setattr(builtins, "__import__", fake_import)


def test_missing_libusb_is_named(open3d_missing_libusb):
    with pytest.raises(DependencyError) as e:
        require_open3d()
    msg = str(e.value)
    assert "libusb-1.0" in msg and "apt-get install libusb-1.0-0" in msg and "\n" not in msg


@pytest.mark.slow
def test_run_without_open3d_still_writes_everything(open3d_missing_libusb, tmp_path):
    """points.ply is written with numpy (gtvo.io.ply): no open3d needed."""
    from gtvo.config import FrontendConfig, OdometryConfig
    from gtvo.io.ply import read_ply_points
    from gtvo.pipeline import run
    from gtvo.datasets.synthetic import make_synthetic_sequence

    rep = run(make_synthetic_sequence(n_frames=8), out=tmp_path,
              config=OdometryConfig(frontend=FrontendConfig(points_per_keyframe=400)))
    assert (tmp_path / "trajectory.tum").is_file() and (tmp_path / "report.json").is_file()
    saved = json.loads((tmp_path / "report.json").read_text())
    assert saved["map_points_written"] > 0 and "map_points_skipped" not in saved
    assert len(read_ply_points(tmp_path / "points.ply")[0]) == saved["map_points_written"]
    assert rep["frames"] == 8 and rep["map_points_left_out"] >= 0
