"""The recipes in examples/ run as a user runs them (``python examples/NN_name.py`` from the
checkout's root, in a fresh interpreter) and print what they promise."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


def run_example(name: str) -> str:
    """The example's stdout; fails with its stderr unless it exits 0."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    done = subprocess.run([sys.executable, str(EXAMPLES / name)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, f"{name} exited {done.returncode}:\n{done.stderr[-3000:]}"
    return done.stdout


def number_after(label: str, text: str) -> float:
    """The first number printed after ``label``."""
    match = re.search(re.escape(label) + r"\s*\(?(-?[0-9.]+)", text)
    assert match, f"{label!r} not in the output:\n{text}"
    return float(match.group(1))


def test_every_example_is_numbered_and_run_here() -> None:
    names = sorted(p.name for p in EXAMPLES.glob("*.py"))
    assert len(names) >= 4 and all(re.fullmatch(r"\d\d_[a-z0-9_]+\.py", n) for n in names), names
    tested = set(re.findall(r'"(\d\d_[a-z0-9_]+\.py)"', Path(__file__).read_text(encoding="utf-8")))
    assert set(names) <= tested, f"examples without a test: {set(names) - tested}"


@pytest.mark.slow  # a fresh interpreter (imports, numba cache) and real work
def test_01_factors_in_a_gtsam_graph() -> None:
    out = run_example("01_factors_in_a_gtsam_graph.py")
    assert number_after("translation error", out) < 10.0  # mm, of a 0.15 m step (measured 2.2)
    stereo_line = out.split("StereoFactor depths")[1]
    assert number_after(": mean error", stereo_line) < number_after("(initial", stereo_line) / 2
    assert number_after("HostPointsFactor depths: mean error", out) < 5.0  # % (measured 2.1, initial 5.3)


@pytest.mark.slow  # a fresh interpreter (imports, numba cache) and real work
def test_02_visual_odometry_frame_by_frame() -> None:
    out = run_example("02_visual_odometry_frame_by_frame.py")
    assert re.search(r"^frame +10 ", out, re.MULTILINE)  # frame by frame
    final_error = float(re.search(r"position error: final [0-9.]+ m \(([0-9.]+) % of", out).group(1))
    assert final_error < 2.0  # % of the path (KITTI_sequence_1: 0.83; synthetic: 0.5)
    assert number_after("last keyframe sigma: rotation", out) > 0


@pytest.mark.slow  # a fresh interpreter (imports, numba cache) and real work
def test_03_pose_graph_with_odometry_calibration() -> None:
    out = run_example("03_pose_graph_with_odometry_calibration.py")
    dead_reckoning = number_after("dead reckoning", out)
    loops_only = number_after("pose graph, loops only", out)
    calibrated = number_after("pose graph + calibration", out)
    assert calibrated < loops_only < dead_reckoning  # measured 0.05 < 0.35 < 1.27 m
    assert calibrated < 0.1 and number_after("joint_calibration", out) < 0.1
    assert abs(number_after("X found (true in brackets):", out) - 1.04) < 0.01  # the wheels' scale


@pytest.mark.slow  # a fresh interpreter (imports, numba cache) and real work
def test_04_read_a_run_report() -> None:
    out = run_example("04_read_a_run_report.py")
    assert "report.json" in out and "covariances.npz" in out
    assert number_after("ATE", out) < 5.0  # cm (measured 0.69)
    mine, the_report = re.search(r"median position sigma: ([0-9.]+) mm \(report: ([0-9.]+) mm\)", out).groups()
    assert mine == the_report


@pytest.mark.slow  # a fresh interpreter and a 25-frame run
@pytest.mark.realdata  # KITTI_sequence_1 when the shared data is there (else the synthetic sequence)
def test_05_custom_window_factor() -> None:
    out = run_example("05_custom_window_factor.py")
    jacobian = float(re.search(r"largest difference to the numerical one ([-+0-9.e]+)", out).group(1))
    assert jacobian < 1e-6  # measured 2e-11
    without = number_after("position error, window (no GPS):", out)
    gtsam_lm = number_after("position error, GTSAM LM with GPS:", out)
    handrolled = number_after("position error, hand-rolled LM with GPS:", out)
    assert gtsam_lm < without / 2 and abs(gtsam_lm - handrolled) < 0.1  # cm (KITTI: 25.0 -> 4.8, both)
