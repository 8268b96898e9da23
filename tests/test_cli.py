"""The `gtvo` command line: help, the main job on small sequences, and bad input (exit 2)."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from gtvo import cli
from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti
from gtvo.io.trajectory_files import read_tum
from gtvo.core.atomic import DIR_MARKER


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "gtvo", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=300)


def copy_with_truncated_frame(log, dest, index):
    """A copy of the KITTI-layout ``log`` at ``dest`` whose left image ``index`` is a truncated
    PNG; returns that image's path."""
    shutil.copytree(log, dest)
    victim = sorted((dest / "image_0").iterdir())[index]
    victim.write_bytes(victim.read_bytes()[:100])
    return victim


@pytest.fixture(scope="module")
def kitti_like(tmp_path_factory):
    """A small synthetic sequence written in the KITTI layout."""
    d = tmp_path_factory.mktemp("seq") / "synthetic_kitti"
    write_sequence_kitti(make_synthetic_sequence(n_frames=8, noise_sigma=1.0), d)
    return d


def test_help_of_every_subcommand(capsys):
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    names = list(sub.choices)
    assert {"run", "demo", "plan", "calibrate-odometry", "synthetic"} <= set(names)
    for name in names:
        with pytest.raises(SystemExit) as e:
            cli.main([name, "--help"])
        assert e.value.code == 0
        assert "usage: gtvo " + name in capsys.readouterr().out


@pytest.mark.slow
def test_run_writes_outputs_and_metrics(kitti_like, tmp_path):
    out = tmp_path / "out"
    r = run_cli("run", kitti_like, "--out", out, "--no-progress", "--points", "600")
    assert r.returncode == 0, r.stderr
    for name in ("trajectory.tum", "report.json", "trajectory.png", "errors.png"):
        assert (out / name).is_file(), name
    rep = json.loads((out / "report.json").read_text())
    # points.ply needs open3d (its wheel needs libusb-1.0): without it the report says why
    assert (out / "points.ply").is_file()
    assert rep["frames"] == 8 and rep["keyframes"] >= 1 and rep["frames_per_second"] > 0
    # exact synthetic data: sub-centimetre ATE; per-frame error measured 5-10 mm per 15 cm step
    # (points on the scene's occlusion edges bias frame-to-keyframe tracking a little)
    assert rep["ate_rmse_m"] < 0.01
    assert rep["drift_percent"] is not None and rep["rpe_trans_rmse_m"] < 0.015
    # every tracked frame's rotation determined well within the tracker's 1 deg bound
    assert 0 < rep["tracking_rotation_sigma_deg_median"] <= rep["tracking_rotation_sigma_deg_max"] < 0.5
    traj = read_tum(out / "trajectory.tum")
    assert len(traj) == 8
    np.testing.assert_allclose(traj.poses[0], np.eye(4), atol=1e-12)
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == [DIR_MARKER]  # no temp files


@pytest.mark.slow
def test_run_with_frame_step_uses_every_kth_frame(kitti_like, tmp_path):
    out = tmp_path / "step2"
    r = run_cli("run", kitti_like, "--out", out, "--no-progress", "--frame-step", "2")
    assert r.returncode == 0, r.stderr
    rep = json.loads((out / "report.json").read_text())
    assert rep["frames"] == 4 and rep["frame_step"] == 2
    traj = read_tum(out / "trajectory.tum")
    np.testing.assert_allclose(traj.timestamps, np.loadtxt(kitti_like / "times.txt")[::2], atol=1e-6)
    assert rep["ate_rmse_m"] < 0.01  # 30 cm steps on exact data


@pytest.mark.parametrize("argv,needle", [
    (["run", "SEQ", "--frame-step", "0"], "--frame-step must be >= 1, got 0"),
    (["run", "SEQ", "--max-frames", "0"], "--max-frames must be >= 1, got 0"),
    (["run", "SEQ", "--points", "10"], "--points must be in [50, 100000], got 10"),
    (["demo", "--points", "-3"], "--points must be in [50, 100000], got -3"),
    (["loops", "SEQ", "--max-frames", "-1"], "--max-frames must be >= 1, got -1"),
])
def test_bad_counts_exit_2_naming_the_flag(kitti_like, tmp_path, capsys, argv, needle):
    argv = [str(kitti_like) if a == "SEQ" else a for a in argv]
    out = ["--out", str(tmp_path / "o")] if argv[0] != "loops" else []
    assert cli.main([*argv, *out, "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0], err
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_run_missing_folder_exit_2(tmp_path):
    r = run_cli("run", tmp_path / "nope", "--out", tmp_path / "o")
    assert r.returncode == 2
    assert "nope" in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_run_malformed_calibration_exit_2(kitti_like, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(kitti_like, bad)
    (bad / "calib.txt").write_text("P0: 1 2 3\nP1: 1 2 3 4 5 6 7 8 9 10 11 12\n")
    r = run_cli("run", bad, "--out", tmp_path / "o", "--no-progress")
    assert r.returncode == 2 and "calib.txt" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.slow
def test_corrupt_frame_mid_sequence_is_skipped_unless_strict(kitti_like, tmp_path):
    bad = tmp_path / "bad"
    victim = copy_with_truncated_frame(kitti_like, bad, 4)
    out = tmp_path / "o"
    r = run_cli("run", bad, "--out", out, "--no-progress", "--points", "600")
    assert r.returncode == 0, r.stderr
    assert victim.name in r.stderr  # reported
    rep = json.loads((out / "report.json").read_text())
    assert rep["skipped_frames"] == [4] and rep["frames"] == 7
    r = run_cli("run", bad, "--out", tmp_path / "o2" / "deep", "--no-progress", "--strict")
    assert r.returncode == 2 and victim.name in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "o2").exists()  # the folders made for the outputs are removed again


def test_loops_skips_a_corrupt_frame_unless_strict(kitti_like, tmp_path, capsys):
    bad = tmp_path / "bad"
    shutil.copytree(kitti_like, bad)
    victim = sorted((bad / "image_1").iterdir())[3]
    victim.write_bytes(victim.read_bytes()[:100])  # truncated PNG
    out = tmp_path / "loops.json"
    assert cli.main(["loops", str(bad), "--out", str(out), "--no-progress"]) == 0
    assert victim.name in capsys.readouterr().err
    rep = json.loads(out.read_text())
    assert rep["skipped_frames"] == [3] and rep["keyframes"] == 7
    assert cli.main(["loops", str(bad), "--strict", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and victim.name in err[0]
    first = sorted((bad / "image_1").iterdir())[0]
    first.write_bytes(b"not a png")
    assert cli.main(["loops", str(bad), "--every", "3", "--max-frames", "4", "--no-progress"]) == 2  # 0 and 3
    assert "no frame of 2 could be read" in capsys.readouterr().err.strip().splitlines()[-1]


@pytest.mark.slow
def test_corrupt_first_frame_exit_2(kitti_like, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(kitti_like, bad)
    first = sorted((bad / "image_1").iterdir())[0]
    first.write_bytes(b"not a png")
    r = run_cli("run", bad, "--out", tmp_path / "o", "--no-progress")
    assert r.returncode == 2 and first.name in r.stderr and "Traceback" not in r.stderr


@pytest.mark.slow
def test_bad_camera_option_exit_2(tmp_path):
    r = run_cli("run", tmp_path, "--camera", "1,2,x,4")
    assert r.returncode == 2 and "--camera" in r.stderr


@pytest.mark.slow
def test_demo_runs(tmp_path):
    out = tmp_path / "demo"
    r = run_cli("demo", "--out", out, "--frames", "6", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "ate_rmse_m" in r.stdout
    rep = json.loads((out / "report.json").read_text())
    assert rep["frames"] == 6 and rep["ate_rmse_m"] < 0.01


@pytest.mark.slow
@pytest.mark.realdata
def test_run_on_kitti_snippet(shared_data, tmp_path):
    seq = shared_data / "kitti_stereo_sample" / "KITTI_sequence_1"
    out = tmp_path / "k"
    r = run_cli("run", seq, "--out", out, "--max-frames", "5", "--no-progress")
    assert r.returncode == 0, r.stderr
    rep = json.loads((out / "report.json").read_text())
    assert rep["frames"] == 5
    # 4 steps of ~1.2 m: frame-to-keyframe tracking measured at ~1 cm per step
    assert rep["ate_rmse_m"] < 0.05


@pytest.mark.slow
def test_demo_with_fixed_lag_backend(tmp_path):
    out = tmp_path / "demo_fl"
    r = run_cli("demo", "--out", out, "--frames", "12", "--no-progress", "--window-backend", "fixed-lag")
    assert r.returncode == 0, r.stderr
    rep = json.loads((out / "report.json").read_text())
    assert rep["mode"] == "window" and rep["window_optimisations"] >= 1 and rep["ate_rmse_m"] < 0.01


@pytest.mark.parametrize("command", ["run", "demo", "batch"])
def test_choices_are_typed_with_dash_or_underscore_and_shown_as_typed(command, capsys):
    from gtvo.commands._common import describe_solvers, odometry_config

    parser = cli.build_parser()
    positional = [] if command == "demo" else ["SEQ"]
    extra = ["--out", "o"] if command == "batch" else []
    for backend, model in (("fixed_lag", "constant_velocity"), ("fixed-lag", "constant-velocity")):
        args = parser.parse_args([command, *positional, *extra, "--window-backend", backend, "--motion-model", model])
        assert args.window_backend == "fixed-lag"  # the flag's own spelling, in messages too
        config = odometry_config(args)
        assert config.window.backend == "fixed_lag" and config.motion_model.model == "constant-velocity"
    with pytest.raises(SystemExit):
        parser.parse_args([command, *positional, *extra, "--window-backend", "fixed lag"])
    assert "invalid choice: 'fixed lag'" in capsys.readouterr().err
    report = {"mode": "window", "tracker_solver": "handrolled", "window_backend": "fixed_lag",
              "window_solver": "gtsam_isam2"}
    assert describe_solvers(report) == "window, tracker handrolled, window fixed-lag back end with gtsam_isam2"
    with pytest.raises(SystemExit):
        parser.parse_args([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert '"fixed-lag": a' in text and "fixed_lag" not in text


@pytest.mark.parametrize("command", ["run", "demo"])
def test_window_backend_without_window_mode_exit_2(kitti_like, tmp_path, capsys, command):
    argv = [command, *([str(kitti_like)] if command == "run" else []), "--out", str(tmp_path / "o"),
            "--mode", "track", "--window-backend", "fixed-lag", "--no-progress"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "--window-backend fixed-lag needs --mode window" in err and "\n" not in err
    assert not (tmp_path / "o").exists()


def test_rig_calibration_without_window_mode_exit_2(kitti_like, tmp_path, capsys):
    config = tmp_path / "track.yaml"
    config.write_text("mode: track\n")
    for how in (["--mode", "track"], ["--config", str(config)]):
        argv = ["run", str(kitti_like), "--out", str(tmp_path / "o"), *how, "--rig-calibration", "--no-progress"]
        assert cli.main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert "--rig-calibration needs --mode window (got --mode track)" in err and "\n" not in err
        assert not (tmp_path / "o").exists()


def test_unusable_output_paths_exit_2_before_any_work(kitti_like, tmp_path, capsys):
    """An --out that is a file, a folder under a file, or a folder where a file is wanted: one
    line naming the path, exit 2, and nothing run (the run would have taken its time first)."""
    a_file = tmp_path / "a_file"
    a_file.write_text("keep me")
    a_dir = tmp_path / "a_dir"
    a_dir.mkdir()
    graph = tmp_path / "two.g2o"
    graph.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    cases = [
        (["run", str(kitti_like), "--out", str(a_file), "--no-progress"], "output folder is a file"),
        (["run", str(kitti_like), "--out", str(a_file / "sub"), "--no-progress"], "cannot create the output folder"),
        (["synthetic", "--out", str(a_file), "--frames", "2"], "output folder is a file"),
        (["posegraph", str(graph), "--out", str(a_dir)], "is a folder"),
        (["posegraph", str(graph), "--plot", str(a_file / "x.png")], "output folder is a file"),
        (["posegraph", str(graph), "--max-iterations", "-3"], "--max-iterations"),
    ]
    for argv, needle in cases:
        assert cli.main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0], (argv, err)
    assert a_file.read_text() == "keep me" and not any(a_dir.iterdir())
    assert cli.main(["posegraph", str(graph), "--json"]) == 0  # the graph itself is fine


def test_no_progress_silences_the_bars(tmp_path, capsys):
    graph = tmp_path / "two.g2o"
    graph.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0.1 1 0 0 1 0 1\n")
    for argv in (["posegraph", str(graph), "--solver", "handrolled"],
                 ["synthetic", "--out", str(tmp_path / "syn"), "--frames", "2"]):
        assert cli.main(argv) == 0
        assert capsys.readouterr().err != ""  # the bar
        assert cli.main([*argv, "--no-progress"]) == 0
        assert capsys.readouterr().err == "", argv


@pytest.mark.slow
def test_two_frame_run_reports_no_ate_instead_of_failing(kitti_like, tmp_path, capsys):
    out = tmp_path / "two"
    assert cli.main(["run", str(kitti_like), "--max-frames", "2", "--out", str(out), "--no-progress"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["ate_rmse_m"] is None and "at least 3" in rep["ate_skipped"]
    assert rep["rpe_trans_rmse_m"] is not None and (out / "trajectory.png").is_file()


@pytest.mark.slow
def test_synthetic_rewrite_leaves_no_stale_frames_and_keeps_foreign_files(tmp_path, capsys):
    out = tmp_path / "syn"
    assert cli.main(["synthetic", "--out", str(out), "--frames", "4"]) == 0
    assert cli.main(["synthetic", "--out", str(out), "--frames", "2"]) == 0
    assert sorted(p.name for p in (out / "image_0").iterdir()) == ["000000.png", "000001.png"]
    assert len((out / "times.txt").read_text().split()) == 2
    (out / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert cli.main(["synthetic", "--out", str(out), "--frames", "3"]) == 2
    assert "notes.txt" in capsys.readouterr().err
    assert (out / "notes.txt").read_text() == "mine" and len(list((out / "image_0").iterdir())) == 2
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp folders left


@pytest.mark.parametrize("argv,needle", [
    (["synthetic", "--frames", "0"], "--frames must be >= 1"),
    (["demo", "--frames", "0", "--no-progress"], "--frames must be >= 1"),
    (["synthetic", "--width", "100000"], "--width and --height must be between 16 and 4096, got 100000x240"),
])
def test_synthetic_sizes_exit_2_one_line(tmp_path, capsys, argv, needle):
    assert cli.main([*argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0]
    assert not (tmp_path / "o").exists()


def test_no_command_writes_over_or_into_its_input(tmp_path, capsys):
    """posegraph --out onto its own input file (once: the input silently replaced), through a link
    too; loops --out inside the sequence folder; calibrate-odometry --plot onto its odometry file:
    one line each, exit 2, the inputs unchanged."""
    graph = tmp_path / "in.g2o"
    graph.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    (tmp_path / "alias.g2o").symlink_to(graph)
    log = write_sequence_kitti(make_synthetic_sequence(n_frames=2, width=160, height=120), tmp_path / "log")
    odom = tmp_path / "odom.txt"
    odom.write_text("0.1 0 0\n0.1 0 0.01\n")
    before = {p: p.read_bytes() for p in (graph, odom)}
    log_before = sorted(str(p) for p in log.rglob("*"))
    for argv, needle in ((["posegraph", str(graph), "--out", str(graph)], "--out is the pose-graph file"),
                         (["posegraph", str(graph), "--out", str(tmp_path / "alias.g2o")], "--out is the pose-graph"),
                         (["posegraph", str(graph), "--plot", str(tmp_path / "x" / ".." / "in.g2o")], "--plot is the"),
                         (["loops", str(log), "--out", str(log / "loops.json")], "--out is inside the sequence folder"),
                         (["calibrate-odometry", str(odom), str(odom), "--plot", str(odom)], "--plot is the odometry")):
        assert cli.main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err, err
    assert {p: p.read_bytes() for p in before} == before
    assert sorted(str(p) for p in log.rglob("*")) == log_before


def test_a_named_command_registers_only_its_parser(capsys):
    """`gtvo CMD` builds CMD's parser alone (start-up time); its help is the one of the whole parser's."""
    def commands(parser):
        return set(next(a for a in parser._actions if a.dest == "command").choices)

    assert commands(cli.build_parser("run")) == {"run"}
    assert commands(cli.build_parser("calibrate-odometry")) == {"calibrate-odometry"}
    assert commands(cli.build_parser("no-such-command")) == commands(cli.build_parser())  # the error lists them all
    assert cli.command_module("calibrate-odometry") == "gtvo.commands.calibrate_odometry"
    assert cli.command_module("nope") is None
    helps = []
    for parser in (cli.build_parser(), cli.build_parser("plan")):
        with pytest.raises(SystemExit):
            parser.parse_args(["plan", "--help"])
        helps.append(capsys.readouterr().out)
    assert helps[0] == helps[1] and "usage: gtvo plan" in helps[0]


def test_exit_without_teardown_joins_threads_and_runs_exit_handlers(monkeypatch):
    """A finished command skips the interpreter's teardown, not its exit handlers or its threads."""
    import threading
    import time

    events: list[str] = []
    worker = threading.Thread(target=lambda: (time.sleep(0.05), events.append("thread")))
    worker.start()
    monkeypatch.setattr(cli.atexit, "_run_exitfuncs", lambda: events.append("atexit"))
    monkeypatch.setattr(cli.threading, "_shutdown", lambda: (worker.join(), events.append("threads joined")))

    def fake_exit(code):
        events.append(f"exit {code}")
        raise SystemExit(code)

    monkeypatch.setattr(cli.os, "_exit", fake_exit)
    with pytest.raises(SystemExit):
        cli._exit_without_teardown(3)
    assert events == ["thread", "threads joined", "atexit", "exit 3"]


def test_unraisable_exceptions_after_a_ctrl_c_are_dropped(monkeypatch):
    """The command's unraisable hook: a KeyboardInterrupt in a finaliser is always dropped; any other
    unraisable exception is printed (passed on) until a Ctrl-C was seen, then dropped (the finalisers
    of objects the interrupt left half-made in a library)."""
    import types

    from gtvo import cli
    from gtvo.core import interrupt

    seen = []
    hook = cli._quiet_interrupts(seen.append)
    other = types.SimpleNamespace(exc_value=AttributeError("half-made"))
    ctrl_c = types.SimpleNamespace(exc_value=KeyboardInterrupt())
    monkeypatch.setattr(interrupt, "_interrupted", False)
    hook(ctrl_c)
    hook(other)
    assert seen == [other]
    monkeypatch.setattr(interrupt, "_interrupted", True)
    hook(other)
    hook(ctrl_c)
    assert seen == [other]
