"""gtvo.datasets.identity: the input's identity in report.json names the input by an absolute path."""

from __future__ import annotations

import os

from gtvo.datasets import open_sequence
from gtvo.datasets.identity import sequence_identity
from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti


def test_the_input_path_is_absolute_whatever_was_typed(tmp_path, monkeypatch):
    write_sequence_kitti(make_synthetic_sequence(n_frames=3, width=96, height=72, seed=1), tmp_path / "data" / "seq")
    monkeypatch.chdir(tmp_path / "data")
    typed = sequence_identity(open_sequence("seq"), "kitti")
    assert typed["path"] == str(tmp_path / "data" / "seq") and os.path.isabs(typed["path"])
    (tmp_path / "link").symlink_to(tmp_path / "data")
    linked = sequence_identity(open_sequence("../link/seq"), "kitti")
    assert linked["path"] == str(tmp_path / "link" / "seq")  # made absolute, the link kept as given
    assert linked["sha256"] == typed["sha256"]
