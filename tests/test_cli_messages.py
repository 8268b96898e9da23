"""Small things a user sees (issue 20, item 10): --help texts, messages that name the missing
key, say "is a folder", print plain numbers, and a quiet stop when stdout's reader leaves."""

from __future__ import annotations

import io as stdio
import sys
from pathlib import Path

import numpy as np
import pytest
from test_datasets import P0, P1, make_euroc, make_kitti

from gtvo import posegraph as pg
from gtvo.cli import main
from gtvo.datasets import open_sequence
from gtvo.errors import InputError, show
from gtvo.evaluation.trajectory import Trajectory
from gtvo.io.trajectory_files import read_trajectory, read_tum
from gtvo.planning.occupancy import read_point_cloud
from gtvo.wheel_calibration import read_motion_pair


def _help(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0
    return " ".join(capsys.readouterr().out.split())  # argparse wraps lines


def _option(text: str, start: str, end: str) -> str:
    """The help of one option: from ``start`` to ``end`` in the options list (after the usage)."""
    first = text.index(start, text.index("options:"))
    return text[first:text.index(end, first)]


def test_posegraph_help_gives_the_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    text = _help(capsys, "posegraph")
    assert "default chordal" in _option(text, "--init {", "--objective {")
    assert "default geodesic" in _option(text, "--objective {", "--strict")


def test_calibrate_odometry_model_and_solver_have_help(capsys: pytest.CaptureFixture[str]) -> None:
    text = _help(capsys, "calibrate-odometry")
    model = _option(text, "--model {", "--solver {")
    solver = _option(text, "--solver {", "--baseline")
    assert "default linear" in model and "diff-drive" in model.split("}", 1)[1]
    assert "default handrolled" in solver and "GTSAM" in solver


def test_loops_help_has_no_rest_markup(capsys: pytest.CaptureFixture[str]) -> None:
    text = _help(capsys, "loops")
    assert "``" not in text and "Place recognition" in text


def test_euroc_missing_yaml_key_is_named(tmp_path: Path) -> None:
    root = make_euroc(tmp_path / "V0")
    yaml = root / "mav0" / "cam0" / "sensor.yaml"
    yaml.write_text("\n".join(l for l in yaml.read_text().splitlines() if not l.startswith("intrinsics")) + "\n")
    with pytest.raises(InputError, match=r"sensor\.yaml: no 'intrinsics' key \(it needs 4 numbers\)$"):
        open_sequence(root)
    yaml.write_text(yaml.read_text().replace("T_BS:\n  cols: 4\n  rows: 4\n  data:", "T_BS:\n  cols: 4\n  rows: 4\n  values:"))
    with pytest.raises(InputError, match=r"T_BS has no 'data' key \(it needs 16 numbers\)$"):
        open_sequence(root)


def test_a_folder_where_a_file_was_expected(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "a_folder.g2o"
    folder.mkdir()
    with pytest.raises(InputError, match="a_folder.g2o: is a folder, not a pose-graph file$"):
        pg.read(folder)
    with pytest.raises(InputError, match="is a folder, not a trajectory file$"):
        read_trajectory(folder, "tum")
    with pytest.raises(InputError, match="is a folder, not a point cloud$"):
        read_point_cloud(folder)
    motions = tmp_path / "odom.txt"
    motions.write_text("1 0 0\n")
    with pytest.raises(InputError, match="is a folder, not a motions file$"):
        read_motion_pair(motions, folder)
    root = make_kitti(tmp_path / "seq")
    with pytest.raises(InputError, match="a_folder.g2o: is a folder, not a"):
        open_sequence(root, ground_truth=folder)
    assert main(["posegraph", str(folder)]) == 2
    assert capsys.readouterr().err.strip().endswith("a_folder.g2o: is a folder, not a pose-graph file")
    with pytest.raises(InputError, match="nothing_here.g2o: pose-graph file not found$"):
        pg.read(tmp_path / "nothing_here.g2o")


def test_messages_print_plain_numbers(tmp_path: Path) -> None:
    assert show(np.float64(1.5)) == "1.5" and show((np.float32(2.0), np.int64(3))) == "(2.0, 3)"
    assert show(np.array([1.0, 2.0])) == "[1.0, 2.0]" and show("x") == "'x'"
    f = tmp_path / "back.tum"
    f.write_text("2 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n")
    with pytest.raises(InputError) as exc:
        read_tum(f)
    assert str(exc.value).endswith("back.tum:2: time goes backwards (2.0 -> 1.0)")
    with pytest.raises(InputError) as exc:
        Trajectory(np.array([2.0, 1.0]), np.tile(np.eye(4), (2, 1, 1)), name="t")
    assert "(2.0 -> 1.0)" in str(exc.value) and "np." not in str(exc.value)
    root = make_kitti(tmp_path / "seq")
    bad = [-v if k == 0 else v for k, v in enumerate(P0)]
    (root / "calib.txt").write_text(" ".join(map(str, bad)) + "\n" + " ".join(map(str, P1)) + "\n")
    with pytest.raises(InputError) as exc:
        open_sequence(root)
    assert "fx=-50.0, fy=50.0" in str(exc.value) and "np." not in str(exc.value)
    root = make_euroc(tmp_path / "V0")
    yaml = root / "mav0" / "cam0" / "sensor.yaml"
    yaml.write_text(yaml.read_text().replace("intrinsics: [50.0", "intrinsics: [-50.0"))
    with pytest.raises(InputError) as exc:
        open_sequence(root)
    assert "invalid intrinsics [-50.0, 50.0, 31.5, 23.5]" in str(exc.value) and "np." not in str(exc.value)


class _ClosedPipe(stdio.StringIO):
    def write(self, text: str) -> int:
        raise BrokenPipeError(32, "Broken pipe")

    def flush(self) -> None:
        raise BrokenPipeError(32, "Broken pipe")


def test_broken_pipe_stops_quietly(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
                                   tmp_path: Path) -> None:
    f = tmp_path / "g.g2o"
    f.write_text("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\n")
    monkeypatch.setattr(sys, "stdout", _ClosedPipe())
    assert main(["posegraph", str(f), "--init", "odometry"]) == 0  # the reader left: not an error
    assert capsys.readouterr().err == ""


def test_a_closed_stdout_pipe_is_exit_0_without_a_word(tmp_path: Path) -> None:
    """`gtvo ... | head -1` when head has gone: a real pipe whose reader is closed (EPIPE)."""
    import os
    import subprocess

    f = tmp_path / "g.g2o"
    f.write_text("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\n")
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        r = subprocess.run([sys.executable, "-m", "gtvo", "posegraph", str(f), "--init", "odometry"],
                           stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert (r.returncode, r.stderr) == (0, "")


@pytest.mark.parametrize("camera", ["1e300,1e300,32,24", "1e-300,1e-300,1e-300,1e-300"])
def test_implausible_camera_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                    camera: str) -> None:
    """``--camera`` with a focal length no pinhole camera has (once a ValueError in the tracker's
    Cholesky): one line naming the option and the value, exit 2, no output folder."""
    from test_datasets import make_tum

    root = make_tum(tmp_path / "tum")
    out = tmp_path / "out"
    assert main(["run", str(root), "--camera", camera, "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--camera" in err and "is implausible" in err and "Traceback" not in err, err
    assert not out.exists()
