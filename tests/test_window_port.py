"""The window's one port (gtvo/odometry/window_port.py): the window in this process and in a worker
process are both a ``WindowPort``; the keyframer drives either the same way; what the worker holds
(poses, covariances, the rig offset, the wheel calibration, every keyframe for the whole-log
refinement) comes back through the port, so wheel odometry and ``--refine`` run with ``--parallel``,
the same bytes in every run."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import json
import subprocess
import sys

import gtsam
import numpy as np
import pytest

from factors.compact_image import CompactGradientImage
from gtvo.config import OdometryConfig
from gtvo.core.image import to_float_gray
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.datasets.synthetic_imu import ImuSimulation
from gtvo.errors import InputError
from gtvo.odometry import keyframer
from gtvo.odometry.keyframe_points import frame_points
from gtvo.odometry.window_link import KeyframeForWindow
from gtvo.odometry.window_port import LocalWindow, WindowPort, open_window
from gtvo.odometry.window_worker import WindowWorker
from gtvo.window.imu import ImuWindow, ImuWindowSettings


def config(parallel: bool, refine: bool = False) -> OdometryConfig:
    base = OdometryConfig()
    return dataclasses.replace(base, window=dataclasses.replace(base.window, parallel=parallel),
                               refine=dataclasses.replace(base.refine, enabled=refine))


@pytest.fixture(scope="module")
def seq():
    return make_synthetic_sequence(n_frames=3, width=160, height=120, step_m=0.1)


def requests(seq, anchor_shift: float | None = None) -> list[KeyframeForWindow]:
    """Keyframes 0 and 1 of ``seq`` at their true poses, 1 tracked against 0; ``anchor_shift``:
    keyframe 1 anchored on keyframe 0 placed that far (m) from where it is (None: no anchor)."""
    out = []
    for k in range(2):
        frame = seq.frame(k)
        left, right = to_float_gray(frame.left, "left"), to_float_gray(frame.right, "right")
        pts = frame_points(frame, left, right, seq.camera, OdometryConfig())
        anchor = None
        if k and anchor_shift is not None:
            T0 = np.array(seq.gt_poses[0], dtype=float)
            T0[:3, 3] += anchor_shift
            anchor = (0, T0)
        out.append(KeyframeForWindow(k, 0.1 * k, gtsam.Pose3(seq.gt_poses[k]), pts, (0, np.zeros(2)) if k else None,
                                     left, right, anchor))
    return out


def test_both_machines_are_one_port(seq):
    local = open_window(seq.camera, config(parallel=False))
    worker = open_window(seq.camera, config(parallel=True))
    try:
        assert isinstance(local, LocalWindow) and isinstance(local, WindowPort)
        assert isinstance(worker, WindowWorker) and isinstance(worker, WindowPort)
        assert local.backend_name == worker.backend_name == "lm"
        assert local.worker_usage() is None and worker.worker_usage().cpu_seconds > 0
    finally:
        worker.close()


def test_the_keyframer_does_not_ask_which_machine_runs():
    """Its code names neither machine, has no ``worker``, reaches nothing with ``getattr``."""
    tree = ast.parse(inspect.getsource(keyframer))
    names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    names |= {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
    names |= {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
    assert not names & {"WindowWorker", "LocalWindow", "WindowLink", "worker", "link", "getattr"}
    assert {"WindowPort", "join", "due", "finish"} <= names


def test_in_this_process_every_update_is_due_at_once_and_no_anchor_moves_a_keyframe(seq):
    plain, anchored = LocalWindow(seq.camera, config(False)), LocalWindow(seq.camera, config(False))
    for window, reqs in ((plain, requests(seq)), (anchored, requests(seq, anchor_shift=0.5))):
        window.join(reqs[0], optimize=False)
        assert window.due() == [] and window.keyframe_indices() == [0]
        window.join(reqs[1], optimize=True)
        updates = window.due()
        assert len(updates) == 1 and [m.index for m in updates[0].members] == [0, 1]
        assert window.finish() == [] and window.keyframe_indices() == [0, 1]
        assert set(window.covariances) == {0, 1} and window.right_brightness() is not None
    for a, b in zip(plain.optimizer.keyframes, anchored.optimizer.keyframes):
        assert np.array_equal(a.pose.matrix(), b.pose.matrix())


def test_the_worker_hands_back_the_state_the_window_in_this_process_has(seq):
    local = LocalWindow(seq.camera, config(False, refine=True))
    worker = WindowWorker(seq.camera, config(True, refine=True))
    try:
        for window in (local, worker):
            first, second = requests(seq)
            window.join(first, optimize=False)
            window.join(second, optimize=True)
        here = local.due()
        assert worker.due() == []  # the worker's update for keyframe 1 is due LAG keyframes later
        there = worker.due(now=True)
        assert len(here) == len(there) == 1 and local.finish() == [] and worker.finish() == []
        assert worker.keyframe_indices() == local.keyframe_indices() == [0, 1]
        for a, b in zip(here[0].members, there[0].members):
            assert np.allclose(a.pose.matrix(), b.pose.matrix(), atol=1e-9)
            assert np.allclose(a.inverse_depth, b.inverse_depth, atol=1e-9)
        assert np.allclose(worker.rig.offset, local.rig.offset, atol=1e-9)
        assert set(worker.covariances) == set(local.covariances) == {0, 1}
        assert worker.right_brightness() == pytest.approx(local.right_brightness(), abs=1e-9)
        # every keyframe, for the whole-log refinement: its images compact, its state the window's
        every = worker.every_keyframe()
        assert [k.index for k in every] == [0, 1] and all(isinstance(k.image, CompactGradientImage) for k in every)
        for a, b in zip(local.every_keyframe(), every):
            assert np.array_equal(a.image.image, b.image.image) and np.array_equal(a.right.image, b.right.image)
            assert np.allclose(a.pose.matrix(), b.pose.matrix(), atol=1e-9)
        cov = worker.rig_offset_covariance()
        assert cov is not None and np.allclose(cov, local.rig_offset_covariance(), rtol=1e-6)
    finally:
        worker.close()


def run(log, out, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "gtvo", "run", str(log), "--out", str(out), "--no-progress",
                           "--config", str(log / "wheel.yaml"), *extra], capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_wheels_and_the_refinement_run_with_the_parallel_window_the_same_bytes_every_run(tmp_path):
    log = tmp_path / "robot"
    made = subprocess.run([sys.executable, "-m", "gtvo", "synthetic", "--out", str(log), "--motion", "ground",
                           "--frames", "40", "--wheel", "arcs", "--wheel-calibration", "1.02,0.98,1.05",
                           "--no-progress"], capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr
    first, second = run(log, tmp_path / "a", "--parallel", "--refine"), run(log, tmp_path / "b", "--parallel", "--refine")
    assert first.returncode == 0 and second.returncode == 0, first.stderr + second.stderr
    a, b = ((tmp_path / d / "trajectory.tum").read_bytes() for d in "ab")
    assert a == b and len(a.splitlines()) == 1 + 40  # the header, every frame
    for d in "ab":
        report = json.loads((tmp_path / d / "report.json").read_text())
        wheel = report["wheel_calibration"]
        assert wheel["sigmas"] is not None  # the worker's marginal covariance came back
        assert report["refine"]["ran"] is True and report["refine"]["keyframes"] >= 5
    assert "window_worker" in json.loads((tmp_path / "a" / "report.json").read_text())
    # the worker estimated the calibration the sequential window does (the same data, another order)
    sequential = run(log, tmp_path / "s", "--refine")
    assert sequential.returncode == 0, sequential.stderr
    par = json.loads((tmp_path / "a" / "report.json").read_text())["wheel_calibration"]
    seq_ = json.loads((tmp_path / "s" / "report.json").read_text())["wheel_calibration"]
    for name in ("left_wheel_scale", "right_wheel_scale", "track_width_scale"):
        assert par[name] == pytest.approx(seq_[name], abs=0.02), name


def test_the_imu_goes_to_the_local_window_and_a_parallel_one_refuses_it_in_one_line():
    seq = make_synthetic_sequence(3, width=120, height=90, imu=ImuSimulation())
    imu = ImuWindow(seq.imu, ImuWindowSettings())
    local = open_window(seq.camera, config(parallel=False), imu=imu)
    try:
        assert isinstance(local, LocalWindow) and local.optimizer.imu is imu
    finally:
        local.close()
    with pytest.raises(InputError, match=r"^window\.parallel does not carry the IMU yet: run it with --no-parallel "
                                         r"\(window\.parallel: false\) or --no-imu$"):
        open_window(seq.camera, config(parallel=True), imu=imu)
