"""gtvo.io.plots: matplotlib loaded in the background, then the run's two plots."""

from __future__ import annotations

import numpy as np
import pytest

from gtvo.evaluation.trajectory import Trajectory
from gtvo.io import plots


@pytest.mark.slow  # imports matplotlib (about a second)
def test_plots_after_loading_in_the_background(tmp_path):
    plots.load_in_background()
    plots.load_in_background()  # once: a second call starts nothing
    n = 20
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 2, 3] = np.arange(n) * 0.5
    est = Trajectory(np.arange(n) * 0.1, poses, name="estimate")
    cov = np.tile(np.eye(3) * 1e-4, (n, 1, 1))
    top = plots.plot_trajectory_top_view(est, est, tmp_path / "t.png", title="top", plane="xz",
                                         ellipses=(poses[:, :3, 3], cov), axis_labels=plots.CAMERA_WORLD_XZ_LABELS)
    errs = plots.plot_errors_over_time(est.timestamps, np.linspace(0, 1, n), tmp_path / "e.png", title="errors")
    assert not plots._loader.is_alive()  # the plots waited for it: one figure drawn at a time
    for path in (top, errs):
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not any(plots._prepared.get(size) for size in plots.PREPARED_SIZES)  # both took the loader's figures
    plots._prepare_figure((8.0, 4.0))  # as the loader does
    prepared = plots.plot_errors_over_time(est.timestamps, np.linspace(0, 1, n), tmp_path / "e2.png", title="errors")
    assert plots._prepared[(8.0, 4.0)] == []  # taken
    fresh = plots.plot_errors_over_time(est.timestamps, np.linspace(0, 1, n), tmp_path / "e3.png", title="errors")
    assert prepared.read_bytes() == fresh.read_bytes() == errs.read_bytes()  # the same PNG either way


def test_loading_starts_once_and_load_now_waits(monkeypatch):
    calls: list[str] = []
    monkeypatch.setattr(plots, "_loader", None)
    monkeypatch.setattr(plots, "_load_matplotlib", lambda: calls.append("loaded"))
    plots.load_in_background()
    first = plots._loader
    plots.load_in_background()
    plots.load_now()
    assert plots._loader is first and not first.is_alive()
    assert calls == ["loaded"]
