"""The Rerun recording of a run (gtvo.io.rerun_log): written by `gtvo demo/run --rerun`, read back
with rerun's own reader and compared with what the run computed."""

from __future__ import annotations

import builtins
import dataclasses
import socket
import sys
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np
import pytest

from gtvo.cli import main as cli_main
from gtvo.config import OdometryConfig
from gtvo.datasets import open_sequence
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.io.rerun_log import residual_colors

FRAMES = 12


# ---------------------------------------------------------------------------------------------
# helpers

def read_rrd(path: Path) -> dict[str, list[dict]]:
    """Every logged row of the recording in ``path`` by entity path (static rows first, then by frame)."""
    from rerun.chunk import RrdReader

    rows: dict[str, list[dict]] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        table = chunk.to_record_batch().to_pydict()
        for i in range(chunk.num_rows):
            rows[chunk.entity_path].append({k: v[i] for k, v in table.items()})
    for entity in rows:
        rows[entity].sort(key=lambda r: r.get("frame", -1))
    return rows


def mat3(flat_columns) -> np.ndarray:
    """Rerun stores 3x3 matrices column by column."""
    return np.asarray(flat_columns, dtype=float).reshape(3, 3).T


def rgba(packed) -> np.ndarray:
    """Rerun's packed 0xRRGGBBAA colours as (N, 3) RGB."""
    c = np.asarray(packed, dtype=np.uint64)
    return np.stack([(c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255], axis=1).astype(int)


def scalars(rows: dict[str, list[dict]], entity: str) -> dict[int, float]:
    return {r["frame"]: r["Scalars:scalars"][0] for r in rows[entity]}


@pytest.fixture(scope="module")
def rerun():
    return pytest.importorskip("rerun", reason="rerun-sdk (the viewer extra) is not installed")


@pytest.fixture(scope="module")
def demo_recording(rerun, tmp_path_factory):
    """`gtvo demo --rerun` (window mode): the recording and the report's folder."""
    root = tmp_path_factory.mktemp("demo")
    out, rrd = root / "out", root / "sub" / "demo.rrd"
    code = cli_main(["demo", "--frames", str(FRAMES), "--out", str(out), "--no-progress", "--rerun", str(rrd)])
    assert code == 0
    return read_rrd(rrd), out


# ---------------------------------------------------------------------------------------------
# the recording of `gtvo demo --rerun`

@pytest.mark.slow
def test_demo_recording_holds_every_entity_on_both_timelines(demo_recording):
    rows, _ = demo_recording
    for entity in ("/world", "/world/camera", "/world/camera/image", "/world/camera/image/tracked", "/world/tracked",
                   "/world/window", "/world/window/axes", "/world/trajectory/estimate",
                   "/world/trajectory/ground_truth", "/world/map/kf_000000", "/plots/tracking/rms",
                   "/plots/tracking/iterations", "/plots/tracking/valid_points", "/plots/frames_per_second",
                   "/plots/rig/right_gain", "/plots/rig/right_offset"):
        assert entity in rows, entity
    cams = rows["/world/camera"]
    assert [r["frame"] for r in cams] == list(range(FRAMES))
    # the synthetic sequence runs at 10 Hz from 0: sensor_time is a duration
    np.testing.assert_allclose([r["sensor_time"].total_seconds() for r in cams], 0.1 * np.arange(FRAMES), atol=1e-9)
    pinhole = [r for r in rows["/world/camera/image"] if "Pinhole:image_from_camera" in r][0]
    seq = make_synthetic_sequence(n_frames=FRAMES, noise_sigma=1.0)
    np.testing.assert_allclose(mat3(pinhole["Pinhole:image_from_camera"][0]), seq.pinhole.K, rtol=1e-6)
    assert pinhole["Pinhole:resolution"][0] == [seq.pinhole.width, seq.pinhole.height]


@pytest.mark.slow
def test_demo_recording_images_trajectories_map_and_plots(demo_recording):
    rows, out = demo_recording
    seq = make_synthetic_sequence(n_frames=FRAMES, noise_sigma=1.0)
    images = [r for r in rows["/world/camera/image"] if "EncodedImage:blob" in r]
    assert len(images) == FRAMES
    decoded = cv2.imdecode(np.asarray(images[5]["EncodedImage:blob"][0], dtype=np.uint8), cv2.IMREAD_GRAYSCALE)
    assert np.abs(decoded.astype(float) - seq.left(5)).mean() < 3.0  # JPEG 90
    # the last estimate strip is the written trajectory; ground truth starts on the first estimate
    final = np.asarray(rows["/world/trajectory/estimate"][-1]["LineStrips3D:strips"][0])
    tum = np.loadtxt(out / "trajectory.tum")
    np.testing.assert_allclose(final, tum[:, 1:4], atol=1e-5)
    gt = np.asarray(rows["/world/trajectory/ground_truth"][0]["LineStrips3D:strips"][0])
    np.testing.assert_allclose(gt, (np.linalg.inv(seq.gt_poses[0]) @ seq.gt_poses)[:, :3, 3], atol=1e-5)
    # the window's keyframes are labelled by frame index; each keyframe has its map points
    labels = rows["/world/window"][-1]["Points3D:labels"]
    keyframes = [int(x) for x in labels]
    assert keyframes[0] == 0 and keyframes == sorted(keyframes)
    for k in keyframes:
        assert len(rows[f"/world/map/kf_{k:06d}"][-1]["Points3D:positions"]) > 100
    # map colours are grey (their intensity), tracked colours run green to red
    grey = rgba(rows["/world/map/kf_000000"][-1]["Points3D:colors"])
    assert np.all(grey[:, 0] == grey[:, 1]) and np.all(grey[:, 1] == grey[:, 2]) and grey.std() > 5
    tracked = rows["/world/camera/image/tracked"][-1]
    assert len(tracked["Points2D:colors"]) == len(tracked["Points2D:positions"]) > 100
    assert np.all(rgba(tracked["Points2D:colors"])[:, 2] == 0)
    # plots: every tracked frame, sensible values; the right camera's gain near 1 on the synthetic rig
    rms = scalars(rows, "/plots/tracking/rms")
    assert sorted(rms) == list(range(1, FRAMES)) and all(0 < v < 2 for v in rms.values())
    assert all(v >= 1 for v in scalars(rows, "/plots/tracking/iterations").values())
    assert all(v > 0 for v in scalars(rows, "/plots/frames_per_second").values())
    assert all(abs(v - 1) < 0.05 for v in scalars(rows, "/plots/rig/right_gain").values())


# ---------------------------------------------------------------------------------------------
# the library: poses and plots equal what the odometry computed

@pytest.mark.slow
def test_track_mode_camera_poses_and_plots_are_the_estimates(rerun, tmp_path):
    from gtvo.pipeline import run
    from gtvo.io.rerun_log import RerunLogger

    seq = make_synthetic_sequence(n_frames=8)
    seq = dataclasses.replace(seq, timestamps=seq.timestamps + 1.3e9)  # Unix times: sensor_time is a date
    seen: list = []

    class Keep:
        def on_start(self, s, config): ...
        def on_frame(self, frame, est, view): seen.append(est)
        def on_finish(self, view, traj, info): ...

    with RerunLogger(save=tmp_path / "t.rrd", jpeg_quality=None) as log:
        run(seq, out=tmp_path / "out", config=OdometryConfig(mode="track"), observers=[log, Keep()])
    rows = read_rrd(tmp_path / "t.rrd")
    cams = rows["/world/camera"]
    assert len(cams) == len(seen) == 8
    for row, est in zip(cams, seen):
        np.testing.assert_allclose(mat3(row["Transform3D:mat3x3"][0]), est.T_world_cam[:3, :3], atol=1e-6)
        np.testing.assert_allclose(row["Transform3D:translation"][0], est.T_world_cam[:3, 3], atol=1e-6)
        assert row["sensor_time"].timestamp() == pytest.approx(est.timestamp, abs=1e-6)
    its = scalars(rows, "/plots/tracking/iterations")
    assert its == {e.index: float(e.tracking.iterations) for e in seen if e.tracking is not None}
    assert "/plots/rig/right_gain" not in rows  # no window in track mode
    raw = [r for r in rows["/world/camera/image"] if "Image:buffer" in r]
    assert len(raw) == 8  # jpeg_quality=None: raw images


def test_residual_colours():
    c = residual_colors(np.array([0.0, -12.0, 24.0, 100.0]), 24.0)
    np.testing.assert_array_equal(c, [[0, 255, 0], [255, 255, 0], [255, 0, 0], [255, 0, 0]])


# ---------------------------------------------------------------------------------------------
# sinks, failures, the missing extra

def test_failed_run_leaves_no_recording(rerun, tmp_path):
    from gtvo.io.rerun_log import RerunLogger

    with pytest.raises(RuntimeError, match="boom"):
        with RerunLogger(save=tmp_path / "x.rrd") as log:
            log.on_start(make_synthetic_sequence(n_frames=2), None)
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_bad_file_name_and_address_exit_2(rerun, tmp_path, capsys):
    assert cli_main(["demo", "--frames", "2", "--out", str(tmp_path / "o"), "--rerun", str(tmp_path / "x.txt")]) == 2
    assert cli_main(["demo", "--frames", "2", "--out", str(tmp_path / "o"), "--rerun", str(tmp_path / "x.rrd"),
                     "--rerun-connect", "localhost:9876"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "x.txt: a Rerun recording is a .rrd file" in err[0] and "rerun+http://" in err[1]
    assert list(tmp_path.iterdir()) == []  # neither x.rrd nor its temporary file
    out = tmp_path / "out"
    assert cli_main(["demo", "--frames", "2", "--out", str(out), "--rerun", str(out / "x.rrd")]) == 2
    assert "inside the output folder" in capsys.readouterr().err and not out.exists()


def test_failed_command_removes_the_folders_it_made_for_the_recording(rerun, tmp_path, capsys):
    rrd = tmp_path / "a" / "b" / "x.rrd"
    assert cli_main(["run", str(tmp_path / "missing"), "--out", str(tmp_path / "o"), "--rerun", str(rrd)]) == 2
    assert "sequence folder not found" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_connect_to_a_running_server(rerun, tmp_path, capsys):
    server = rerun.RecordingStream("viewer_stand_in")
    url = server.serve_grpc(grpc_port=_free_port())
    try:
        code = cli_main(["demo", "--frames", "3", "--out", str(tmp_path), "--no-progress", "--rerun-connect", url])
    finally:
        server.disconnect()
    assert code == 0
    assert "did not take the data" not in capsys.readouterr().err


def test_connect_to_an_absent_viewer_is_one_line_at_once(rerun, tmp_path, capsys):
    """Nothing listens at the address: one line naming it, exit 2, before the run (before: the run
    went on, the SDK retried for about 10 s and printed its coloured log lines into stderr)."""
    url = f"rerun+http://127.0.0.1:{_free_port()}/proxy"
    assert cli_main(["demo", "--frames", "2", "--out", str(tmp_path / "o"), "--no-progress",
                     "--rerun-connect", url]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--rerun-connect {url}: no Rerun viewer answers at 127.0.0.1:" in err, err
    assert "\x1b[" not in err and not (tmp_path / "o").exists()


def test_a_recording_inside_the_log_is_refused(rerun, tmp_path, capsys):
    from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti

    log = write_sequence_kitti(make_synthetic_sequence(n_frames=2, width=160, height=120), tmp_path / "log")
    before = sorted(p.name for p in log.iterdir())
    assert cli_main(["run", str(log), "--out", str(tmp_path / "o"), "--rerun", str(log / "x.rrd")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is inside the log" in err, err
    assert sorted(p.name for p in log.iterdir()) == before


def test_without_rerun_sdk_one_line_names_the_extra(tmp_path, monkeypatch, capsys):
    real_import = builtins.__import__

    def fake_import(name, *args, **kwargs):
        if name == "rerun" or name.startswith("rerun."):
            raise ImportError("No module named 'rerun'")
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "rerun", raising=False)
    monkeypatch.setattr(builtins, "__import__", fake_import)
    code = cli_main(["demo", "--frames", "2", "--out", str(tmp_path / "o"), "--rerun", str(tmp_path / "d.rrd")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and 'pip install "gtvo[viewer]"' in err
    assert not (tmp_path / "d.rrd").exists() and not (tmp_path / "o").exists()


@pytest.mark.slow
@pytest.mark.realdata
def test_rgbd_run_is_recorded_with_unix_times_and_ground_truth(rerun, shared_data, tmp_path):
    root = shared_data / "rgbd_dataset_freiburg3_teddy_first20"
    if not root.is_dir():
        pytest.skip(f"{root} not found")
    rrd = tmp_path / "tum.rrd"
    args = ["run", str(root), "--out", str(tmp_path / "out"), "--max-frames", "4", "--no-progress", "--rerun", str(rrd)]
    assert cli_main(args) == 0
    rows = read_rrd(rrd)
    cams = rows["/world/camera"]
    first = open_sequence(root).timestamps[0]
    assert len(cams) == 4 and cams[0]["sensor_time"].timestamp() == pytest.approx(first, abs=1e-6)  # a date
    gt = np.asarray(rows["/world/trajectory/ground_truth"][0]["LineStrips3D:strips"][0])
    np.testing.assert_allclose(gt[0], 0.0, atol=1e-6)  # starts on the first estimate, the origin
    assert len(gt) == 4 and np.linalg.norm(gt[-1]) < 0.5
    assert "/plots/tracking/rms" in rows and "/plots/rig/right_gain" not in rows  # RGB-D: no right camera
