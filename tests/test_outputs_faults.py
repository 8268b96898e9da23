"""Honest outputs under faults (issue 20): a usable map, outputs replaced as a set, inputs never
damaged, what ran is what is reported, one line on Ctrl-C."""

from __future__ import annotations

import dataclasses
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gtvo import cli
from gtvo.commands._common import print_report
from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti
from gtvo.errors import InputError, caused_by_interrupt
from gtvo.evaluation.trajectory import Trajectory
from gtvo.io import outputs
from gtvo.core.atomic import DIR_MARKER
from gtvo.io.outputs import RUN_OUTPUT_NAMES, check_run_output_dir, top_view, write_run_outputs
from gtvo.io.plots import CAMERA_WORLD_XZ_LABELS
from gtvo.core.map_points import MAX_RELATIVE_DEPTH_SIGMA, MapPoints, constrained_mask
from gtvo.config import FrontendConfig, OdometryConfig
from gtvo.report import map_points_figures
from gtvo.odometry import VisualOdometry

KITTI = Path("kitti_stereo_sample") / "KITTI_sequence_1"
ROOT = Path(__file__).resolve().parents[1]


def run_cli(*args, cwd=None, timeout=600):
    return subprocess.run([sys.executable, "-m", "gtvo", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout)


@pytest.fixture(scope="module")
def kitti_like(tmp_path_factory):
    """A small synthetic sequence written in the KITTI layout."""
    d = tmp_path_factory.mktemp("seq") / "synthetic_kitti"
    write_sequence_kitti(make_synthetic_sequence(n_frames=8, noise_sigma=1.0), d)
    return d


@pytest.fixture(scope="module")
def kitti_real(shared_data):
    folder = shared_data / KITTI
    if not folder.is_dir():
        pytest.skip(f"{folder} is absent")
    return folder


# -- 1. a map that can be used ------------------------------------------------------------------

def test_constrained_mask_rules():
    d = np.array([0.1, 0.1, -0.1, 0.0, np.nan, 0.1, 1e-12, 0.1])
    sigma = np.array([0.01, 0.05, 0.01, 0.01, 0.01, np.inf, 0.01, 0.01])
    seen = np.array([2, 2, 2, 2, 2, 2, 2, 1])
    keep, out = constrained_mask(d, sigma ** 2, seen)
    # 0: 10 % sigma; 1: 50 % > 1/3; 2-4: not positive / not finite; 5: infinite variance;
    # 6: a point the optimiser drove to infinity; 7: only its host saw it
    assert keep.tolist() == [True, False, False, False, False, False, False, False]
    assert out == {"not_positive_or_finite": 4, "depth_uncertain": 2, "too_few_observing_keyframes": 1}
    # the bound is on the relative sigma itself: just inside and just outside
    b = MAX_RELATIVE_DEPTH_SIGMA
    keep, _ = constrained_mask(np.ones(2), np.array([0.99 * b, 1.01 * b]) ** 2)
    assert keep.tolist() == [True, False]
    # no window: the observation rule is not applied
    keep, out = constrained_mask(d[:1], sigma[:1] ** 2, None)
    assert keep.tolist() == [True] and "too_few_observing_keyframes" not in out


@pytest.fixture(scope="module")
def window_vo():
    seq = make_synthetic_sequence(n_frames=12)
    vo = VisualOdometry(seq.camera, OdometryConfig(frontend=FrontendConfig(points_per_keyframe=300)))
    for f in seq:
        vo.process(f)
    assert len(vo.keyframes) >= 2
    return vo


def test_map_points_leave_out_points_at_infinity_and_count_them(window_vo):
    vo = window_vo
    before = vo.map_points()
    total = sum(len(k.points) for k in vo.keyframes)
    assert before.written + before.left_out_total == total and before.written > 0.8 * total
    kf = vo.keyframes[0]
    old = kf.points
    d = old.inverse_depth.copy()
    d[:5] = 1e-13  # what the window did to a few KITTI points: 1e13 m away
    d[5:8] = -d[5:8]
    try:
        kf.points = dataclasses.replace(old, inverse_depth=d)
        after = vo.map_points()
        raw, _ = vo.keyframer.point_cloud()
    finally:
        kf.points = old
    assert np.max(np.linalg.norm(raw, axis=1)) > 1e9  # the unfiltered cloud holds them
    assert np.max(np.linalg.norm(after.points, axis=1)) < 100.0
    assert after.written + after.left_out_total == total
    assert after.left_out["not_positive_or_finite"] >= 3 and after.left_out_total >= before.left_out_total + 8


def test_observation_rule_applies_to_keyframes_a_window_optimisation_included(window_vo):
    """A window run's points must have been seen from a second keyframe; with one keyframe (a static
    camera) no optimisation ran and the points are exported as measured, as in track mode."""
    assert window_vo.map_points().left_out["too_few_observing_keyframes"] > 0
    seq = make_synthetic_sequence(n_frames=2)
    written = {}
    for mode in ("window", "track"):
        vo = VisualOdometry(seq.camera, OdometryConfig(frontend=FrontendConfig(points_per_keyframe=300), mode=mode))
        for f in seq:
            vo.process(f)
        assert len(vo.keyframes) == 1
        m = vo.map_points()
        assert "too_few_observing_keyframes" not in m.left_out, (mode, m)
        written[mode] = m.written
    assert written["window"] == written["track"] > 0


@pytest.mark.slow
def test_readme_chain_run_then_plan_on_real_data(kitti_real, tmp_path, open3d):
    """README: `gtvo run SEQ --out out/` then `gtvo plan --map out/points.ply --start 0,5 --goal 0,30`."""
    out = tmp_path / "out"
    r = run_cli("run", kitti_real, "--out", out, "--no-progress")
    assert r.returncode == 0, r.stderr
    rep = json.loads((out / "report.json").read_text())
    assert rep["map_points_written"] > 5000 and rep["map_points_left_out"] > 0
    pts = np.asarray(open3d.io.read_point_cloud(str(out / "points.ply")).points)
    assert len(pts) == rep["map_points_written"]
    # a 60 m drive: every exported point within a few hundred metres (was 4e14 m)
    assert np.max(np.linalg.norm(pts, axis=1)) < 1000.0
    p = run_cli("plan", "--map", out / "points.ply", "--start", "0,5", "--goal", "0,30", "--out", tmp_path / "p.png")
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "p.png").is_file()


@pytest.mark.slow
@pytest.mark.parametrize("options,backend", [(["--window-backend", "fixed-lag"], "fixed_lag"),
                                             (["--solver", "gtsam"], "lm"), (["--loop-closure"], "lm"),
                                             (["--mode", "track"], None)], ids=["fixed-lag", "gtsam", "loop-closure", "track"])
def test_map_of_every_backend_can_be_planned_on(kitti_real, tmp_path, open3d, options, backend):
    out = tmp_path / "out"
    r = run_cli("run", kitti_real, "--out", out, "--no-progress", *options)
    assert r.returncode == 0, r.stderr
    rep = json.loads((out / "report.json").read_text())
    assert rep["map_points_written"] > 5000
    assert rep.get("loop_closure_solver") == ("gtsam_gnc_lm" if "--loop-closure" in options else None)
    assert rep.get("window_backend") == backend
    pts = np.asarray(open3d.io.read_point_cloud(str(out / "points.ply")).points)
    assert np.max(np.linalg.norm(pts, axis=1)) < 1000.0
    p = run_cli("plan", "--map", out / "points.ply", "--start", "0,5", "--goal", "0,30", "--json")
    assert p.returncode == 0, p.stderr


# -- 2. outputs survive an interrupt as a set ---------------------------------------------------

def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def _estimate(seq, shift: float) -> Trajectory:
    poses = seq.gt_poses.copy()
    poses[:, 0, 3] += shift * np.arange(len(poses))
    return Trajectory(seq.timestamps.copy(), poses, name="est")


@pytest.fixture(scope="module")
def small_seq():
    return make_synthetic_sequence(n_frames=6)


def _points(n: int = 50) -> MapPoints:
    rng = np.random.default_rng(0)
    return MapPoints(rng.normal(size=(n, 3)), rng.uniform(0, 255, n), {"depth_uncertain": 1})


@pytest.mark.slow
def test_a_plain_run_leaves_no_stale_file_of_an_earlier_loop_closure_run(small_seq, tmp_path):
    out = tmp_path / "out"
    est = _estimate(small_seq, 0.01)
    write_run_outputs(out, est, small_seq, {"frames": 6}, loop_closed=est)
    assert (out / "trajectory_loop_closed.tum").is_file()
    write_run_outputs(out, _estimate(small_seq, 0.02), small_seq, {"frames": 6})
    assert not (out / "trajectory_loop_closed.tum").exists()
    assert "loop_closed_ate_rmse_m" not in json.loads((out / "report.json").read_text())
    assert not [p for p in tmp_path.iterdir() if p.name != "out"]  # no temporary folder left


@pytest.mark.slow
@pytest.mark.parametrize("step", range(10))
def test_interrupt_at_every_step_of_the_output_phase_keeps_the_old_set(small_seq, tmp_path, monkeypatch, step):
    """Ctrl-C before each file of the output phase and around the swap: the old set, whole."""
    out = tmp_path / "out"
    write_run_outputs(out, _estimate(small_seq, 0.01), small_seq, {"frames": 6}, points=_points(),
                      loop_closed=_estimate(small_seq, 0.0))
    old = _snapshot(out)
    calls = {"n": 0}

    def interrupting(fn):
        def wrapper(*a, **k):
            calls["n"] += 1
            if calls["n"] == step:
                raise KeyboardInterrupt
            return fn(*a, **k)
        return wrapper

    for name in ("write_tum", "plot_trajectory_top_view", "plot_errors_over_time", "write_ply_points",
                 "write_json", "check_replaceable_dir"):
        monkeypatch.setattr(outputs, name, interrupting(getattr(outputs, name)))
    import gtvo.core.atomic as atomic

    monkeypatch.setattr(atomic, "_swap_in", interrupting(atomic._swap_in))
    monkeypatch.setattr(atomic, "check_replaceable_dir", interrupting(atomic.check_replaceable_dir))
    if step == 0:  # the whole phase uninterrupted: the new set
        points = _points(30)
        write_run_outputs(out, _estimate(small_seq, 0.02), small_seq, {"frames": 6, **map_points_figures(points)},
                          points=points)
        rep = json.loads((out / "report.json").read_text())
        ply = {"points.ply"} if rep["map_points_written"] is not None else set()  # None: no open3d (reason given)
        assert set(_snapshot(out)) == {DIR_MARKER, "trajectory.tum", "report.json", "trajectory.png",
                                       "errors.png"} | ply
        assert rep["map_points_written"] in (30, None) and rep["map_points_left_out"] == 1
        return
    with pytest.raises(KeyboardInterrupt):
        write_run_outputs(out, _estimate(small_seq, 0.02), small_seq, {"frames": 6}, points=_points(30))
    assert calls["n"] == step
    assert _snapshot(out) == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no temporary folder left


@pytest.mark.slow
def test_interrupt_during_the_swap_is_held_back_until_the_new_set_is_in(small_seq, tmp_path, monkeypatch):
    """A SIGINT between the two renames of the swap: the new set is in place, then the interrupt."""
    import gtvo.core.atomic as atomic

    out = tmp_path / "out"
    write_run_outputs(out, _estimate(small_seq, 0.01), small_seq, {"frames": 6}, loop_closed=_estimate(small_seq, 0))
    real_replace = os.replace
    seen = {"n": 0}
    # Python's own handler, whatever this process inherited (a background job starts with SIGINT
    # ignored, and then there is nothing to hold back); conftest restores the inherited one
    signal.signal(signal.SIGINT, signal.default_int_handler)

    def replace_then_signal(src, dst):
        folder = Path(src).is_dir()
        real_replace(src, dst)
        if folder:
            seen["n"] += 1
            if seen["n"] == 1:  # the old folder has just gone aside
                signal.raise_signal(signal.SIGINT)

    monkeypatch.setattr(os, "replace", replace_then_signal)
    with pytest.raises(KeyboardInterrupt):
        write_run_outputs(out, _estimate(small_seq, 0.02), small_seq, {"frames": 6})
    assert seen["n"] == 2
    assert "trajectory_loop_closed.tum" not in _snapshot(out) and (out / "report.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_an_interrupt_inside_compiled_code_is_an_interrupt(monkeypatch, capsys):
    """numba reports a KeyboardInterrupt raised while a compiled function returns as
    'SystemError: CPUDispatcher(...) returned a result with an exception set'."""
    import gtvo.commands.run as run_command

    def compiled_call(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("CPUDispatcher(<function warp_residuals>) returned a result with an exception set")

    monkeypatch.setattr(run_command, "main", compiled_call)  # registered as the command's func
    assert cli.main(["run", "somewhere"]) == 130
    assert capsys.readouterr().err.strip().splitlines() == ["gtvo run: interrupted"]
    assert not caused_by_interrupt(SystemError("a real crash"))


def test_an_interrupt_while_open3d_loads_is_not_a_missing_open3d(monkeypatch):
    """Ctrl-C while open3d's extension initialises: 'ImportError: initialization failed' with the
    interrupt as context; the run must stop, not write everything but points.ply and exit 0."""
    import builtins

    from gtvo.core.optional import require_open3d

    real_import = builtins.__import__

    def interrupted_import(name, *args, **kwargs):
        if name == "open3d":
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt:
                raise ImportError("initialization failed")
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "open3d", raising=False)
    monkeypatch.setattr(builtins, "__import__", interrupted_import)
    with pytest.raises(KeyboardInterrupt):
        require_open3d()


@pytest.mark.slow
def test_sigint_at_random_moments_leaves_the_old_set_or_the_new_set(kitti_like, tmp_path):
    """A real `gtvo run` sent SIGINT after random delays (seeded): exit 130 with one line (or 0 when
    it finished first), and the output folder holds the earlier run's set or this run's, whole."""
    base = tmp_path / "base"
    r = run_cli("run", kitti_like, "--out", base, "--no-progress", "--max-frames", "5", "--loop-closure")
    assert r.returncode == 0, r.stderr
    old = _snapshot(base)
    t0 = time.perf_counter()
    r = run_cli("--version")  # the interpreter and gtvo's imports: SIGINT before them is Python's, not gtvo's
    startup = time.perf_counter() - t0
    t0 = time.perf_counter()
    r = run_cli("run", kitti_like, "--out", tmp_path / "full", "--no-progress")
    assert r.returncode == 0, r.stderr
    full = time.perf_counter() - t0
    new_names = set(_snapshot(tmp_path / "full"))
    # the moments: after the start-up (with a margin), spread over the run as measured just now; a
    # fixed floor would miss the run once it takes less than the floor
    first = 1.5 * startup
    last = max(first + 0.1, 0.9 * full)
    rng = random.Random(20)
    outcomes = []
    for trial in range(8):
        work = tmp_path / f"t{trial}"
        work.mkdir()
        out = work / "out"
        shutil.copytree(base, out)
        proc = subprocess.Popen([sys.executable, "-m", "gtvo", "run", str(kitti_like), "--out", str(out),
                                 "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                # a shell's background job starts with SIGINT ignored: the child would inherit it
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        # the first trial halfway between the imports and the end (a run certainly in progress, even
        # when the machine's load changed since the measurement); the others at random moments
        time.sleep(startup + 0.5 * (full - startup) if trial == 0 else rng.uniform(first, last))
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=300)
        outcomes.append(proc.returncode)
        assert proc.returncode in (0, 130), (trial, err)
        if proc.returncode == 130:
            assert err.strip().splitlines() == ["gtvo run: interrupted"], err
        now = _snapshot(out)
        if now != old:
            assert set(now) == new_names, sorted(now)
            rep = json.loads(now["report.json"])
            assert rep["frames"] == 8 and "loops_detected" not in rep
            assert len([ln for ln in now["trajectory.tum"].decode().splitlines() if not ln.startswith("#")]) == 8
        assert sorted(p.name for p in work.iterdir()) == ["out"]  # no temporary folder left
    assert 130 in outcomes


# -- 8. outputs never damage inputs or unrelated files ------------------------------------------

@pytest.mark.slow
def test_output_folder_in_the_input_is_refused(kitti_like, tmp_path):
    seq_copy = tmp_path / "seq"
    shutil.copytree(kitti_like, seq_copy)
    before = {p: sorted(q.name for q in p.iterdir()) for p in (seq_copy, seq_copy / "image_0", seq_copy / "image_1")}
    for out, needle in ((seq_copy / "image_0", "image folder"), (seq_copy / "image_1" / "x", "image folder"),
                        (seq_copy, "input folder")):
        r = run_cli("run", seq_copy, "--out", out, "--no-progress")
        assert r.returncode == 2, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and needle in lines[0], lines
    assert {p: sorted(q.name for q in p.iterdir()) for p in before} == before


def test_no_output_into_the_log_or_below_it_whatever_the_spelling(kitti_like, tmp_path, capsys):
    """A folder inside the log (not only its image folders), reached through '..', a symbolic link
    to the log or one to its image folder: one line, exit 2, the log untouched."""
    seq_copy = tmp_path / "seq"
    shutil.copytree(kitti_like, seq_copy)
    (tmp_path / "alias").symlink_to(seq_copy)
    (tmp_path / "frames").symlink_to(seq_copy / "image_0")
    (tmp_path / "elsewhere").mkdir()
    before = sorted(str(p.relative_to(seq_copy)) for p in seq_copy.rglob("*"))
    for out, needle in ((seq_copy / "results", "inside the input folder"),
                        (tmp_path / "elsewhere" / ".." / "seq" / "results", "inside the input folder"),
                        (tmp_path / "alias", "is the input folder"),
                        (tmp_path / "alias" / "results" / "deeper", "inside the input folder"),
                        (tmp_path / "frames", "one of the input's image folders")):
        assert cli.main(["run", str(seq_copy), "--out", str(out), "--no-progress"]) == 2, out
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err, err
    assert sorted(str(p.relative_to(seq_copy)) for p in seq_copy.rglob("*")) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["alias", "elsewhere", "frames", "seq"]


def test_an_output_folder_that_is_a_link_loop_or_a_file_is_one_line(kitti_like, tmp_path, capsys):
    loop = tmp_path / "loop"
    loop.symlink_to("loop")
    (tmp_path / "a_file").write_text("mine\n")
    for out, needle in ((loop, "loop: output folder is a symbolic link loop"),
                        (loop / "inside", "symbolic link loop"),
                        (tmp_path / "a_file", "a_file: output folder is a file"),
                        (tmp_path / "a_file" / "below", "a_file")):
        assert cli.main(["run", str(kitti_like), "--out", str(out), "--no-progress"]) == 2, out
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err and "Traceback" not in err, err
    assert (tmp_path / "a_file").read_text() == "mine\n"


@pytest.mark.slow
def test_an_image_that_is_a_link_loop_is_a_skipped_frame_named_as_such(kitti_like, tmp_path, capsys):
    """An image file that is a symbolic link loop (once a RuntimeError from Path.resolve() after the
    whole run) is an unreadable frame: skipped with one line saying why (--strict: exit 2)."""
    seq_copy = tmp_path / "seq"
    shutil.copytree(kitti_like, seq_copy)
    image = seq_copy / "image_0" / "000002.png"
    image.unlink()
    image.symlink_to(image.name)
    assert cli.main(["run", str(seq_copy), "--out", str(tmp_path / "out"), "--no-progress", "--max-frames", "4"]) == 0
    err = capsys.readouterr().err
    assert "skipping frame 2:" in err and "000002.png: image file is a symbolic link loop" in err, err
    assert "Traceback" not in err and (tmp_path / "out" / "report.json").is_file()
    assert cli.main(["run", str(seq_copy), "--out", str(tmp_path / "strict"), "--no-progress", "--max-frames", "4",
                     "--strict"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "image file is a symbolic link loop" in err, err


def test_a_second_run_into_a_held_output_folder_is_refused(kitti_like, tmp_path, capsys):
    """Concurrent runs into one --out: the second is refused at once (before: all reported success
    and the last replaced the others' outputs)."""
    from gtvo.core.atomic import output_lock

    out = tmp_path / "out"
    with output_lock(out):
        assert cli.main(["run", str(kitti_like), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "another gtvo process" in err and str(out) in err, err
    assert not out.exists()


@pytest.mark.slow
def test_the_next_run_removes_a_killed_runs_staging_folder(kitti_like, tmp_path):
    """SIGTERM while the outputs are written leaves a hidden staging folder beside --out; the next
    run into that --out removes it (gtvo's own staging names only)."""
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-c", _KILLED_WHILE_WRITING.format(root=str(ROOT), out=str(out))],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not any(p.name.startswith(".out.") and p.is_dir() for p in tmp_path.iterdir()):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    proc.terminate()
    proc.communicate(timeout=120)
    left = [p.name for p in tmp_path.iterdir() if p.name.startswith(".out.") and not p.name.endswith(".lock")]
    assert left, "the killed writer left no staging folder: the case is not built"
    (tmp_path / ".notes").mkdir()  # not gtvo's: stays
    assert cli.main(["run", str(kitti_like), "--out", str(out), "--no-progress", "--max-frames", "3"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [".notes", "out"]


_KILLED_WHILE_WRITING = """
import sys, time
sys.path.insert(0, {root!r})
from gtvo.core.atomic import atomic_dir
from gtvo.io.outputs import RUN_OUTPUT_NAMES, RUN_WRITER
with atomic_dir({out!r}, RUN_OUTPUT_NAMES, RUN_WRITER) as staging:
    (staging / "trajectory.tum").write_text("half")
    time.sleep(600)
"""


@pytest.mark.slow
def test_unrelated_files_in_the_output_folder_are_never_overwritten(kitti_like, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "report.json").write_text('{"my": "own report"}\n')
    r = run_cli("run", kitti_like, "--out", out, "--no-progress", "--max-frames", "3")
    assert r.returncode == 2 and "not written by gtvo run" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in out.iterdir()) == ["report.json"]
    assert (out / "report.json").read_text() == '{"my": "own report"}\n'
    (out / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="holds other files"):
        check_run_output_dir(out, make_synthetic_sequence(n_frames=2))
    # an earlier run's folder (marked) is replaced, an empty one filled
    empty = tmp_path / "empty"
    empty.mkdir()
    for _ in range(2):
        r = run_cli("run", kitti_like, "--out", empty, "--no-progress", "--max-frames", "3")
        assert r.returncode == 0, r.stderr
    assert (empty / DIR_MARKER).is_file() and set(p.name for p in empty.iterdir()) <= RUN_OUTPUT_NAMES | {DIR_MARKER}


# -- 9. what ran is what is reported ------------------------------------------------------------

@pytest.mark.slow
def test_fixed_lag_run_reports_isam2_and_every_solver(kitti_like, tmp_path):
    out = tmp_path / "out"
    r = run_cli("run", kitti_like, "--out", out, "--no-progress", "--max-frames", "4", "--window-backend",
                "fixed-lag")
    assert r.returncode == 0, r.stderr
    rep = json.loads((out / "report.json").read_text())
    assert (rep["tracker_solver"], rep["window_backend"], rep["window_solver"]) == ("handrolled", "fixed_lag",
                                                                                  "gtsam_isam2")
    first = r.stdout.splitlines()[0]
    assert "window fixed-lag back end" in first and "gtsam_isam2" in first and "tracker handrolled" in first
    r = run_cli("run", kitti_like, "--out", out, "--no-progress", "--max-frames", "4", "--solver", "gtsam")
    rep = json.loads((out / "report.json").read_text())
    assert (rep["tracker_solver"], rep["window_backend"], rep["window_solver"]) == ("gtsam", "lm", "gtsam")
    assert "loop_closure_solver" not in rep


# -- 10. console, plots, library noise ----------------------------------------------------------

def test_summary_values_share_one_column(capsys):
    print_report({"frames": 51, "ate_rmse_m": 0.028, "loop_closed_ate_rmse_m": 0.03,
                  "loop_closed_drift_percent": 0.5, "map_points_written": 9000, "out": "x"})
    lines = capsys.readouterr().out.splitlines()[:-1]
    starts = {len(ln) - len(ln.rstrip().split()[-1]) for ln in lines}
    assert len(lines) == 5 and len(starts) == 1, lines


def test_top_view_of_a_camera_frame_world_names_its_axes(small_seq):
    ref = Trajectory(small_seq.timestamps, small_seq.gt_poses)
    assert np.allclose(ref.poses[0], np.eye(4))
    assert top_view(ref) == {"plane": "xz", "axis_labels": CAMERA_WORLD_XZ_LABELS}
    assert top_view(None)["plane"] == "xz"
    moved = ref.poses.copy()
    moved[:, 2, 3] += 5.0  # a world that is not the first camera (e.g. a mocap frame)
    assert top_view(Trajectory(ref.timestamps, moved)) == {"plane": "auto"}


@pytest.mark.slow
def test_corrupt_png_is_one_line_without_libpng_noise(kitti_like, tmp_path):
    seq_copy = tmp_path / "seq"
    shutil.copytree(kitti_like, seq_copy)
    first = seq_copy / "image_0" / "000000.png"
    data = bytearray(first.read_bytes())
    data[20] ^= 1  # inside the IHDR chunk: a CRC error for libpng
    first.write_bytes(bytes(data))
    r = run_cli("run", seq_copy, "--out", tmp_path / "out", "--no-progress")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gtvo run: error:") and "CRC" in lines[0], lines
    # the same damage mid-sequence: skipped with one warning line, exit 0 (README)
    first.write_bytes((kitti_like / "image_0" / "000000.png").read_bytes())
    third = seq_copy / "image_0" / "000002.png"
    data = bytearray(third.read_bytes())
    data[20] ^= 1
    third.write_bytes(bytes(data))
    r = run_cli("run", seq_copy, "--out", tmp_path / "out", "--no-progress", "--max-frames", "4")
    assert r.returncode == 0, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning: skipping frame 2") and "CRC" in lines[0], lines


@pytest.mark.slow
def test_corrupt_ply_is_one_line_without_rply_noise(tmp_path, open3d):
    bad = tmp_path / "bad.ply"
    bad.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                   "property float z\nend_header\n1 2 3\n1 2 abc\n4 5 6\n")
    r = run_cli("plan", "--map", bad, "--start", "0,5", "--goal", "0,30")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "corrupt point cloud" in lines[0] and "RPly" in lines[0], lines
