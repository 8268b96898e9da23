"""The window beside the tracker (``window.parallel``, issue 34): the same bytes in every run and
under load, close to the sequential order, and clean ends (a bad frame, an error or death of the
worker, Ctrl-C): one line, the exit code of the sequential run, no process left behind."""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from gtvo.config import OdometryConfig
from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti
from gtvo.errors import InputError
from gtvo.odometry import VisualOdometry
from gtvo.odometry.window_link import KeyframeForWindow
from gtvo.odometry.window_worker import WindowWorker, WindowWorkerError
from tests.test_batch_interrupt import end_group, live_processes_in_group
from tests.test_cli import copy_with_truncated_frame


def config(parallel: bool | str, worker_threads: int | None = None, every_frame: bool = False) -> OdometryConfig:
    """The default settings with ``window.parallel``; ``every_frame``: a keyframe at every frame (as
    KITTI at 10 Hz makes them)."""
    base = OdometryConfig()
    keyframes = dataclasses.replace(base.keyframes, max_motion=0.0) if every_frame else base.keyframes
    return dataclasses.replace(base, window=dataclasses.replace(base.window, parallel=parallel,
                                                                worker_threads=worker_threads), keyframes=keyframes)


def run_vo(seq, parallel: bool | str, worker_threads: int | None = None, cfg: OdometryConfig | None = None
           ) -> tuple[np.ndarray, dict[int, np.ndarray], VisualOdometry]:
    cfg = cfg or config(parallel, worker_threads)
    with VisualOdometry(seq.camera, cfg, imu=getattr(seq, "imu", None)) as vo:
        for frame in seq:
            vo.process(frame)
        vo.finish()
    poses = np.stack([e.T_world_cam for e in vo.estimates])
    return poses, {k: vo.covariance(k) for k in (kf.index for kf in vo.keyframes)}, vo


def busy_loops(n: int) -> list[subprocess.Popen]:
    """``n`` processes spinning on a core each (the load of other jobs on the machine)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


@pytest.mark.slow
def test_parallel_window_gives_the_same_bytes_every_run_and_under_load(kitti_snippet):
    seq = kitti_snippet(max_frames=14)
    first, cov1, vo = run_vo(seq, parallel=True)
    assert isinstance(vo.window, WindowWorker) and len(vo.window_results) >= 5
    load = busy_loops(3)
    try:
        second, cov2, _ = run_vo(seq, parallel=True)
    finally:
        for p in load:
            p.kill()
            p.wait()
    assert first.tobytes() == second.tobytes()
    assert cov1.keys() == cov2.keys()
    assert all((cov1[k] is None and cov2[k] is None) or cov1[k].tobytes() == cov2[k].tobytes() for k in cov1)
    # the worker's two kernel threads (the default) change when a host's residuals are computed, not the bytes
    one_thread, cov3, _ = run_vo(seq, parallel=True, worker_threads=1)
    assert first.tobytes() == one_thread.tobytes()
    assert all((cov1[k] is None and cov3[k] is None) or cov1[k].tobytes() == cov3[k].tobytes() for k in cov1)
    sequential, _, seq_vo = run_vo(seq, parallel=False)
    assert not isinstance(seq_vo.window, WindowWorker)
    # a different order of the same work: close to the sequential run (cm over 14 KITTI frames), not equal
    assert 0 < np.max(np.abs(first[:, :3, 3] - sequential[:, :3, 3])) < 0.05


def test_a_worker_error_comes_back_as_the_same_exception_and_the_worker_ends():
    seq = make_synthetic_sequence(n_frames=2, width=160, height=120)
    worker = WindowWorker(seq.camera, config(True))
    pixels = np.array([[40.0, 40.0], [60.0, 50.0]])
    from gtvo.frontend import KeyframePoints  # noqa: PLC0415

    bad = KeyframePoints(pixels, np.array([-1.0, 0.5]), np.array([1e-3, 1e-3]), np.array([100.0, 120.0]))
    frame = seq.frame(0)
    left = np.asarray(frame.left, np.float32)
    right = np.asarray(frame.right, np.float32)
    import gtsam  # noqa: PLC0415

    worker.join(KeyframeForWindow(0, 0.0, gtsam.Pose3(), bad, None, left, right), optimize=True)
    with pytest.raises(InputError, match="keyframe 0: inverse depths and variances must be finite and > 0"):
        worker.finish()
    assert worker._process.poll() is not None  # ended with the error


@pytest.mark.slow
def test_a_killed_worker_is_one_error_at_the_next_reply(kitti_snippet):
    seq = kitti_snippet(max_frames=8)
    vo = VisualOdometry(seq.camera, config(True))
    frames = iter(seq)
    for _ in range(3):
        vo.process(next(frames))
    os.kill(vo.window.pid, signal.SIGKILL)
    with pytest.raises(WindowWorkerError, match="ended unexpectedly"):
        for frame in frames:
            vo.process(frame)
        vo.finish()
    vo.close()


@pytest.fixture(scope="module")
def stereo_log(tmp_path_factory):
    d = tmp_path_factory.mktemp("par") / "log"
    write_sequence_kitti(make_synthetic_sequence(n_frames=24, width=320, height=240, noise_sigma=1.0), d)
    return d


def start_run(log, out, *extra: str) -> subprocess.Popen:
    """`gtvo run --parallel` in a session of its own (a process group, as a shell job)."""
    return subprocess.Popen([sys.executable, "-m", "gtvo", "run", str(log), "--out", str(out), "--no-progress",
                             "--parallel", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


@pytest.mark.slow
def test_a_bad_frame_with_the_parallel_window_is_one_line_exit_2_and_no_process_left(stereo_log, tmp_path):
    bad = tmp_path / "bad"
    victim = copy_with_truncated_frame(stereo_log, bad, 6)
    proc = start_run(bad, tmp_path / "o", "--strict")
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 2 and victim.name in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert end_group(proc.pid) == []
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_ctrl_c_with_the_parallel_window_is_one_line_exit_130_and_no_process_left(stereo_log, tmp_path):
    proc = start_run(stereo_log, tmp_path / "full")
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    proc = start_run(stereo_log, tmp_path / "o")
    deadline = time.monotonic() + 120
    # wait for the worker (the second process of the group), then interrupt the whole group
    while len(live_processes_in_group(proc.pid)) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert end_group(proc.pid) == []
    assert proc.returncode in (0, 130), err
    if proc.returncode == 130:
        assert err.strip().splitlines() == ["gtvo run: interrupted"], err
        assert not (tmp_path / "o").exists()
    else:  # the run had finished: its outputs are whole
        assert (tmp_path / "o" / "trajectory.tum").read_bytes() == (tmp_path / "full" / "trajectory.tum").read_bytes()


def test_no_parallel_flag_and_config_key(tmp_path):
    from gtvo import cli  # noqa: PLC0415

    parser = cli.build_parser()
    args = parser.parse_args(["run", "x", "--no-parallel"])
    assert args.no_parallel and not args.parallel
    with pytest.raises(SystemExit):
        parser.parse_args(["run", "x", "--parallel", "--no-parallel"])
    from gtvo.config import as_config  # noqa: PLC0415

    assert as_config({"window": {"parallel": True}}).window.parallel is True
    assert as_config({"window": {"parallel": "auto"}}).window.parallel == "auto"
    assert OdometryConfig().window.parallel is False


def test_a_batch_log_runs_its_window_in_its_own_process_unless_its_config_asks():
    from gtvo.batching import one_core_per_log  # noqa: PLC0415
    from gtvo.batching.overrides import apply_overrides  # noqa: PLC0415

    assert one_core_per_log(apply_overrides(OdometryConfig(), None)).window.parallel is False  # one core per log
    asked = apply_overrides(OdometryConfig(), {"window": {"parallel": True}})
    assert one_core_per_log(asked).window.parallel is True


def test_a_parallel_runs_summary_says_what_the_worker_spent_and_a_sequential_one_has_no_worker():
    """The front end's seconds_by_stage of a parallel run shows the wait; the window's own stages are
    the worker's, reported under window_worker (asked before the worker ends)."""
    from gtvo.pipeline import process_sequence  # noqa: PLC0415

    seq = make_synthetic_sequence(10, width=160, height=120)
    _, _, parallel = process_sequence(seq, OdometryConfig(window=dataclasses.replace(
        OdometryConfig().window, parallel=True, worker_threads=2)), warn=lambda m: None)
    worker = parallel["window_worker"]
    assert worker["cpu_seconds"] > 0 and worker["max_rss_mib"] > 0
    assert worker["kernel_threads"] == 2 and 0.0 <= worker["pool_cpu_seconds"] < worker["cpu_seconds"]
    assert worker["seconds_by_stage"].get("linearisation", 0.0) > 0.0
    assert parallel["seconds_by_stage"].get("linearisation", 0.0) == 0.0  # not the front end's
    _, _, sequential = process_sequence(seq, OdometryConfig(), warn=lambda m: None)
    assert "window_worker" not in sequential and sequential["seconds_by_stage"]["linearisation"] > 0.0


@pytest.fixture(scope="module")
def imu_sequence():
    """A fast-turning synthetic log with its IMU (docs/imu.md), small: 18 frames, 1.7 s."""
    from gtvo.datasets.synthetic_imu import ImuSimulation  # noqa: PLC0415

    return make_synthetic_sequence(n_frames=18, width=160, height=120, motion="swerve", imu=ImuSimulation())


@pytest.mark.slow
def test_the_imu_rides_with_the_window_in_its_worker(imu_sequence):
    """Where no keyframe's window overlaps the next frames (frames between keyframes) the worker's
    order is the sequential one: the same bytes. With keyframes at every frame the front end
    tracks on with the IMU's state two keyframes old: the same bytes every run and under load,
    within 5 mm (a quarter of the log's ATE scale) of the sequential run's, and the IMU initialised alike."""
    sequential, _, seq_vo = run_vo(imu_sequence, False)
    parallel, _, vo = run_vo(imu_sequence, True)
    assert isinstance(vo.window, WindowWorker) and vo.imu.initialised and seq_vo.imu.initialised
    assert vo.keyframer.schedule.overlapping == 0 and parallel.tobytes() == sequential.tobytes()
    every = config(False, every_frame=True)
    sequential, _, seq_vo = run_vo(imu_sequence, False, cfg=every)
    first, _, vo = run_vo(imu_sequence, True, cfg=dataclasses.replace(every, window=dataclasses.replace(
        every.window, parallel=True)))
    assert vo.keyframer.schedule.overlapping >= 14 and vo.imu.initialised and vo.imu.init_kind == seq_vo.imu.init_kind
    assert vo.imu.factors_added > 0 and set(vo.imu.biases) >= {vo.keyframes[-1].index}
    load = busy_loops(3)
    try:
        second, _, _ = run_vo(imu_sequence, True, cfg=vo.config)
    finally:
        for p in load:
            p.kill()
            p.wait()
    assert first.tobytes() == second.tobytes()
    assert 0 < np.max(np.abs(first[:, :3, 3] - sequential[:, :3, 3])) < 0.005
    assert np.allclose(vo.imu.gravity, seq_vo.imu.gravity, atol=0.02)


@pytest.mark.slow
def test_auto_moves_the_window_to_the_worker_where_keyframes_come_at_every_frame(imu_sequence):
    """``auto``: sequential up to the decision keyframe, then the worker; the same
    bytes in every run and under load; a log with frames between keyframes never starts one."""
    from gtvo.odometry.window_schedule import AUTO_DECISION_KEYFRAME  # noqa: PLC0415

    seq = make_synthetic_sequence(n_frames=AUTO_DECISION_KEYFRAME + 4, width=160, height=120)
    first, cov1, vo = run_vo(seq, "auto", cfg=config("auto", every_frame=True))
    assert isinstance(vo.window, WindowWorker) and vo.keyframer.schedule.keyframes == len(seq)
    load = busy_loops(3)
    try:
        second, cov2, _ = run_vo(seq, "auto", cfg=vo.config)
    finally:
        for p in load:
            p.kill()
            p.wait()
    assert first.tobytes() == second.tobytes()
    assert all((cov1[k] is None and cov2[k] is None) or cov1[k].tobytes() == cov2[k].tobytes() for k in cov1)
    sequential, _, _ = run_vo(seq, False, cfg=config(False, every_frame=True))
    # the frames whose keyframes left the window before the move: the sequential order's, to the bit
    before = AUTO_DECISION_KEYFRAME - OdometryConfig().window.size
    assert first[:before].tobytes() == sequential[:before].tobytes() and first.tobytes() != sequential.tobytes()
    _, _, between = run_vo(imu_sequence, "auto")  # frames between keyframes: nothing overlaps
    assert not isinstance(between.window, WindowWorker)
