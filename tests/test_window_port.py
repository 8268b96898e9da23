"""The window's one port (gtvo/odometry/window_port.py): the window in this process and in a worker
process are both a ``WindowPort``; the keyframer drives either the same way; what the worker holds
(poses, covariances, the rig offset, the wheel calibration, every keyframe for the whole-log
refinement, the IMU's state) comes back through the port, so wheel odometry, the IMU and
``--refine`` run with ``--parallel``, the same bytes in every run; a window in this process moves
to a worker from its state (``window.parallel: auto``) and continues there as it would have here."""

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
from gtvo.odometry import keyframer, window_worker
from gtvo.odometry.keyframe_points import frame_points
from gtvo.odometry.window_link import KeyframeForWindow
from gtvo.odometry.window_port import LocalWindow, WindowPort, open_window
from gtvo.odometry.window_worker import WindowWorker
from gtvo.window.imu import ImuWindow, ImuWindowSettings, _Seen
from gtvo.window.wheel import WheelCalibration, WheelSettings


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


def _imu_state(window) -> tuple[str, int, bool]:
    """A probe run on the window where it is (pickled: module level): its IMU's type, readings, and
    whether it is the window's own copy."""
    return type(window.imu).__name__, len(window.imu.readings.times), window.imu.initialised


@pytest.mark.slow
def test_the_imu_goes_to_either_machine_and_a_worker_carries_its_own_copy():
    seq = make_synthetic_sequence(3, width=120, height=90, imu=ImuSimulation())
    imu = ImuWindow(seq.imu, ImuWindowSettings())
    local = open_window(seq.camera, config(parallel=False), imu=imu)
    worker = open_window(seq.camera, config(parallel=True), imu=imu)
    try:
        assert isinstance(local, LocalWindow) and local.optimizer.imu is imu
        assert isinstance(worker, WindowWorker) and worker.sensors == (imu,)  # the front end's, updated
        assert worker.inspect(_imu_state) == local.inspect(_imu_state) == ("ImuWindow", len(seq.imu.times), False)
    finally:
        worker.close()
    with pytest.raises(InputError, match=r"^the IMU is used by the 'lm' window backend only: drop --window-backend "
                                         r"fixed-lag or add --no-imu$"):
        fixed_lag = dataclasses.replace(config(parallel=True), window=dataclasses.replace(
            config(parallel=True).window, backend="fixed_lag"))
        open_window(seq.camera, fixed_lag, imu=imu)


def test_a_sensors_window_state_brings_a_copy_up_to_date():
    """What the worker hands back of the IMU (:meth:`ImuWindow.window_state`) makes the front end's
    copy predict as the worker's does, bit for bit, and report its biases; the wheel calibration's
    carries its estimate."""
    seq = make_synthetic_sequence(3, width=120, height=90, imu=ImuSimulation())
    worker_copy, front = ImuWindow(seq.imu, ImuWindowSettings()), ImuWindow(seq.imu, ImuWindowSettings())
    assert front.predict_at(0.15) is None
    worker_copy.gravity0 = np.array([0.0, 9.80665, 0.0])
    worker_copy.tilt = np.array([0.01, 0.0, -0.02])
    for i in range(3):
        worker_copy.velocities[i] = np.array([0.0, 0.0, 1.0 + i])
        worker_copy.biases[i] = np.full(6, 0.01 * i)
        worker_copy._seen[i] = _Seen(0.1 * i, gtsam.Pose3(seq.gt_poses[i]))
    front.take_window_state(worker_copy.window_state([1, 2]))  # the window's keyframes: 1 and 2
    assert front.initialised and set(front.velocities) == set(front.biases) == {1, 2}
    expected, got = worker_copy.predict_at(0.15), front.predict_at(0.15)
    assert expected is not None and np.array_equal(expected.matrix(), got.matrix())
    assert front.report()["gyro_bias"] == worker_copy.report()["gyro_bias"]
    wheel_front, wheel_worker = WheelCalibration(WheelSettings(np.eye(4)), None), WheelCalibration(WheelSettings(np.eye(4)), None)
    wheel_worker.estimate = wheel_worker.estimate * 1.01
    wheel_front.take_window_state(wheel_worker.window_state([1, 2]))
    assert np.array_equal(wheel_front.estimate, wheel_worker.estimate)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_a_window_moved_to_a_worker_continues_there_as_it_would_have_here(method, monkeypatch):
    """``window.parallel: auto``: a window in this process moves to a worker with its state (forked:
    this process's own; spawned: pickled, images as grey levels, gradients built again) and its next
    optimisation there equals, to the bit, the one the window in this process makes."""
    if method == "fork" and window_worker.START_METHOD != "fork":
        pytest.skip("os.fork is used on Linux only")
    monkeypatch.setattr(window_worker, "START_METHOD", method)
    seq = make_synthetic_sequence(n_frames=3, width=160, height=120, step_m=0.1)
    here, moved = LocalWindow(seq.camera, config(False)), LocalWindow(seq.camera, config(False))
    for window in (here, moved):
        for request in requests(seq):
            window.join(request, optimize=request.index == 1)
        (update,) = window.due()
    third = dataclasses.replace(requests(seq)[1], index=2, timestamp=0.2, T_world_cam=gtsam.Pose3(seq.gt_poses[2]),
                                tracked=(1, np.zeros(2)), anchor=(1, update.members[-1].pose.matrix()))
    frame = seq.frame(2)
    third.left, third.right = to_float_gray(frame.left, "left"), to_float_gray(frame.right, "right")
    third.points = frame_points(frame, third.left, third.right, seq.camera, OdometryConfig())
    worker = moved.on_second_core()
    try:
        assert isinstance(worker, WindowWorker) and worker.on_second_core() is worker
        assert worker.keyframe_indices() == [0, 1] and worker.covariances.keys() == here.covariances.keys()
        here.join(third, optimize=True)
        worker.join(third, optimize=True)
        (a,), (b,) = here.due(), worker.due(now=True)
        assert [m.index for m in a.members] == [m.index for m in b.members] == [0, 1, 2]
        for x, y in zip(a.members, b.members):
            assert x.pose.matrix().tobytes() == y.pose.matrix().tobytes()
            assert x.inverse_depth.tobytes() == y.inverse_depth.tobytes()
        assert a.result.cost == b.result.cost and a.result.initial_cost == b.result.initial_cost
    finally:
        worker.close()
