"""KITTI raw drives (gtvo.datasets.kitti_raw): made-up drives, OXTS records whose poses are worked
out by hand, bad input, and the real drive in ../shared/data."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from gtvo.datasets import detect_format, open_sequence
from gtvo.datasets.kitti_raw import (EARTH_RADIUS_M, camera_ground_truth, parse_kitti_time, read_rectifying_rotation,
                                     read_rigid)
from gtvo.errors import InputError

W, H = 64, 48
FX, CX, CY = 50.0, 31.5, 23.5
BASELINE = 0.25
RAW_DRIVE = "kitti_raw_2011_09_26_drive_0001_stereo"
#: KITTI's velodyne -> camera axes (x_cam = -y_velo, y_cam = -z_velo, z_cam = x_velo)
R_VELO_CAM = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])


def _fmt(values) -> str:
    return " ".join(f"{float(x):.12e}" for x in np.asarray(values).reshape(-1))


def _projection(tx: float) -> np.ndarray:
    """``K [I | t]`` with ``t = (tx, 0, 0)``: a rectified camera moved by tx along x from cam0."""
    K = np.array([[FX, 0, CX], [0, FX, CY], [0, 0, 1]])
    return np.c_[K, K @ np.array([tx, 0.0, 0.0])]


def _texture(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, (H, W), dtype=np.uint8)


def make_raw(drive: Path, n: int = 3, calib_dir: Path | None = None, colour: bool = False,
             R_rect: np.ndarray | None = None, T_velo_imu: np.ndarray | None = None,
             T_cam_velo: np.ndarray | None = None, oxts: list[list[float]] | None = None,
             t2: float = -0.06) -> Path:
    """A raw drive with ``n`` frames; calibration files in ``calib_dir`` (default: the drive)."""
    drive.mkdir(parents=True, exist_ok=True)
    calib_dir = drive if calib_dir is None else calib_dir
    names = ("image_02", "image_03") if colour else ("image_00", "image_01")
    for cam in names:
        (drive / cam / "data").mkdir(parents=True)
        for i in range(n):
            image = _texture(i)
            cv2.imwrite(str(drive / cam / "data" / f"{i:010d}.png"), np.dstack([image] * 3) if colour else image)
        stamps = [f"2011-09-26 13:02:{25 + i // 10:02d}.{(i % 10) * 100_000_000 + 1:09d}" for i in range(n)]
        (drive / cam / "timestamps.txt").write_text("\n".join(stamps) + "\n")
    R_rect = np.eye(3) if R_rect is None else R_rect
    (calib_dir / "calib_cam_to_cam.txt").write_text(
        "calib_time: 09-Jan-2012 13:57:47\ncorner_dist: 9.950000e-02\n"
        f"R_rect_00: {_fmt(R_rect)}\nP_rect_00: {_fmt(_projection(0.0))}\n"
        f"P_rect_01: {_fmt(_projection(-BASELINE))}\nP_rect_02: {_fmt(_projection(-t2))}\n"
        f"P_rect_03: {_fmt(_projection(-t2 - BASELINE))}\n")
    for name, T in (("calib_imu_to_velo.txt", T_velo_imu), ("calib_velo_to_cam.txt", T_cam_velo)):
        T = np.eye(4) if T is None else T
        (calib_dir / name).write_text(f"calib_time: 25-May-2012 16:47:16\nR: {_fmt(T[:3, :3])}\nT: {_fmt(T[:3, 3])}\n")
    if oxts is not None:
        (drive / "oxts" / "data").mkdir(parents=True)
        for i, record in enumerate(oxts):
            if record is not None:  # 6 pose fields + 24 more (velocities, accelerations, ...) as KITTI writes
                (drive / "oxts" / "data" / f"{i:010d}.txt").write_text(_fmt(list(record) + [0.0] * 24) + "\n")
    return drive


def _rigid(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def _degrees_east(metres: float, lat_deg: float = 0.0) -> float:
    """The longitude step (deg) of ``metres`` east at ``lat_deg`` (a parallel of radius er cos(lat))."""
    return math.degrees(metres / (EARTH_RADIUS_M * math.cos(math.radians(lat_deg))))


# ---------------------------------------------------------------------------------------------
# layout, camera, timestamps

@pytest.mark.parametrize("calib_above", [False, True])
def test_made_up_drive_in_both_calibration_places(tmp_path, calib_above):
    date = tmp_path / "2011_09_26"
    drive = make_raw(date / "2011_09_26_drive_0001_sync", n=4, calib_dir=date if calib_above else None)
    assert detect_format(drive) == "kitti_raw"
    seq = open_sequence(drive)
    assert len(seq) == 4 and seq.kind == "stereo" and seq.gt_poses is None
    assert seq.pinhole.fx == FX and seq.pinhole.cx == CX and seq.pinhole.cy == CY
    assert (seq.pinhole.width, seq.pinhole.height) == (W, H)
    assert seq.camera.baseline == pytest.approx(BASELINE)
    np.testing.assert_allclose(np.diff(seq.timestamps), 0.1, atol=1e-6)
    np.testing.assert_array_equal(seq.left(2), _texture(2).astype(np.float32))
    assert len(open_sequence(drive, max_frames=2)) == 2


def test_colour_pair_when_there_is_no_gray_pair(tmp_path):
    drive = make_raw(tmp_path / "drive", colour=True, t2=-0.06)
    seq = open_sequence(drive)
    assert seq.camera.baseline == pytest.approx(BASELINE)
    np.testing.assert_allclose(seq.left(1), _texture(1), atol=0.51)  # gray from equal BGR channels


def test_kitti_time_is_read_to_the_nanosecond_digits():
    # 1970-01-02 00:00:01.25 is 86401.25 s after the epoch (read as UTC)
    assert parse_kitti_time("1970-01-02 00:00:01.250000000", Path("t"), 1) == pytest.approx(86401.25, abs=1e-9)
    assert parse_kitti_time("2011-09-26 13:02:25.967790592", Path("t"), 1) % 1 == pytest.approx(0.9677906, abs=1e-6)
    with pytest.raises(InputError, match="t:3: not a KITTI timestamp"):
        parse_kitti_time("2011-09-26 13:02:25.96x", Path("t"), 3)


def test_bad_input_names_the_file(tmp_path):
    drive = make_raw(tmp_path / "drive")
    (drive / "image_01" / "data" / "0000000001.png").unlink()
    with pytest.raises(InputError, match="missing right image"):
        open_sequence(drive)
    drive = make_raw(tmp_path / "drive2")
    stamps = drive / "image_00" / "timestamps.txt"
    stamps.write_text("\n".join(stamps.read_text().splitlines()[:2]) + "\n")
    with pytest.raises(InputError, match=r"timestamps.txt: 2 timestamps for 3 images"):
        open_sequence(drive)
    drive = make_raw(tmp_path / "drive3")
    calib = drive / "calib_cam_to_cam.txt"
    calib.write_text(calib.read_text().replace("P_rect_01", "P_rect_9"))
    with pytest.raises(InputError, match="calib_cam_to_cam.txt: no P_rect_01 line"):
        open_sequence(drive)
    drive = make_raw(tmp_path / "drive4", oxts=[[0, 0, 0, 0, 0, 0]] * 3)
    (drive / "calib_imu_to_velo.txt").unlink()
    with pytest.raises(InputError, match="calib_imu_to_velo.txt not found"):
        open_sequence(drive)
    drive = make_raw(tmp_path / "drive5", oxts=[[0, 0, 0, 0, 0, 0], [95.0, 0, 0, 0, 0, 0], None])
    with pytest.raises(InputError, match=r"0000000001.txt:1: latitude 95.0 outside"):
        open_sequence(drive)
    drive = make_raw(tmp_path / "drive6", T_velo_imu=np.diag([1.0, 1.0, -1.0, 1.0]), oxts=[[0] * 6] * 3)
    with pytest.raises(InputError, match="calib_imu_to_velo.txt: R is not a rotation"):
        open_sequence(drive)


@pytest.mark.parametrize("text", ["", "\n   \n", "# a comment\n", "junk 1 2 3\n"])
def test_empty_blank_or_unlabelled_cam_to_cam_is_one_line_in_run_info_and_loops(tmp_path, capsys, text):
    from gtvo.cli import main

    drive = make_raw(tmp_path / "drive")
    (drive / "calib_cam_to_cam.txt").write_text(text)
    with pytest.raises(InputError, match=r"calib_cam_to_cam.txt: (empty calibration file: )?no P_rect_00 or "
                                         r"P_rect_01 line"):
        open_sequence(drive)
    capsys.readouterr()
    for command in (["run", str(drive), "--out", str(tmp_path / "out"), "--no-progress"], ["loops", str(drive)]):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "calib_cam_to_cam.txt" in err and "Traceback" not in err
    assert main(["info", str(drive)]) == 0  # info describes a log it can list; the reason on one line
    out = capsys.readouterr().out
    assert "gtvo run would fail: " in out and "calib_cam_to_cam.txt: " in out


# ---------------------------------------------------------------------------------------------
# OXTS -> ground truth, poses worked out by hand

def test_oxts_mercator_at_the_equator_and_at_49_degrees(tmp_path):
    # identity calibration: the rectified camera is the IMU; world = the IMU at the first record
    d = 10.0
    drive = make_raw(tmp_path / "a", oxts=[[0, 0, 0, 0, 0, 0], [0, _degrees_east(d), 2.0, 0, 0, 0], None])
    gt = open_sequence(drive).gt_poses
    np.testing.assert_allclose(gt[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(gt[1], _rigid(np.eye(3), [d, 0, 2.0]), atol=1e-6)  # d east, 2 m up
    assert np.all(np.isnan(gt[2]))  # no record, no pose
    # at 49 deg a degree of longitude is cos(49 deg) shorter: the devkit's Mercator scale keeps metres
    lat = 49.0
    north = 64.0  # metres: Mercator y grows by er dlat / cos(lat), times the scale cos(lat0)
    dlat = math.degrees(north / EARTH_RADIUS_M)
    drive = make_raw(tmp_path / "b", oxts=[[lat, 8.4, 110, 0, 0, 0], [lat, 8.4 + _degrees_east(d, lat), 110, 0, 0, 0],
                                           [lat + dlat, 8.4, 110, 0, 0, 0]])
    gt = open_sequence(drive).gt_poses
    np.testing.assert_allclose(gt[1][:3, 3], [d, 0, 0], atol=1e-6)
    np.testing.assert_allclose(gt[2][:3, 3], [0, north, 0], atol=north * 2e-5)  # 2nd order in dlat


def test_oxts_angles_and_the_first_record_as_world(tmp_path):
    d = 5.0
    # heading north (yaw 90 deg) at the first record: east is the IMU's -y (its right)
    drive = make_raw(tmp_path / "a", oxts=[[0, 0, 0, 0, 0, math.pi / 2], [0, _degrees_east(d), 0, 0, 0, math.pi / 2],
                                           [0, 0, 0, 0.3, -0.2, math.pi / 2 + 0.1]])
    gt = open_sequence(drive).gt_poses
    np.testing.assert_allclose(gt[1], _rigid(np.eye(3), [0, -d, 0]), atol=1e-6)
    # R = Rz(yaw) Ry(pitch) Rx(roll), relative to the first heading
    np.testing.assert_allclose(gt[2][:3, :3], _rot("z", 0.1) @ _rot("y", -0.2) @ _rot("x", 0.3), atol=1e-12)


def test_oxts_through_kitti_calibration_to_the_rectified_cameras(tmp_path):
    d = 7.0
    T_velo_imu = _rigid(np.eye(3), [-0.81, 0.32, -0.80])
    T_cam_velo = _rigid(R_VELO_CAM, [0.0, -0.08, -0.27])
    oxts = [[0, 0, 0, 0, 0, 0], [0, _degrees_east(d), 0, 0, 0, 0], [0, 0, 0, 0, 0, math.radians(30)]]
    drive = make_raw(tmp_path / "a", T_velo_imu=T_velo_imu, T_cam_velo=T_cam_velo, oxts=oxts)
    gt = open_sequence(drive).gt_poses
    # the camera looks along the IMU's x (forward): driving d forward moves it d along its own z
    np.testing.assert_allclose(np.linalg.inv(gt[0]) @ gt[1], _rigid(np.eye(3), [0, 0, d]), atol=1e-6)
    # turning left by 30 deg about the IMU's z (up) turns the camera about its -y (its up is -y)
    rel = np.linalg.inv(gt[0]) @ gt[2]
    np.testing.assert_allclose(rel[:3, :3], _rot("y", -math.radians(30)), atol=1e-9)
    # the world is the IMU at the first record: the camera sits at inv(T_cam_imu)'s translation
    T_cam_imu = T_cam_velo @ T_velo_imu
    np.testing.assert_allclose(gt[0], np.linalg.inv(T_cam_imu), atol=1e-9)
    # R_rect_00 turns the rectified camera: its optical axis in cam0 is R_rect_00^T e_z
    R_rect = _rot("x", 0.02)
    drive = make_raw(tmp_path / "b", R_rect=R_rect, oxts=oxts)
    gt = open_sequence(drive).gt_poses
    np.testing.assert_allclose(gt[0][:3, 2], R_rect.T @ [0, 0, 1], atol=1e-12)
    # the colour pair: cam2 is the rectified cam0 moved by t_2 = K^-1 P_rect_02[:, 3] = (-t2, 0, 0)
    drive = make_raw(tmp_path / "c", colour=True, t2=-0.06, oxts=oxts)
    gt = open_sequence(drive).gt_poses
    np.testing.assert_allclose(gt[0][:3, 3], [-0.06, 0, 0], atol=1e-9)


def test_ground_truth_option_takes_an_oxts_folder(tmp_path):
    other = make_raw(tmp_path / "other", oxts=[[0, 0, 0, 0, 0, 0], [0, _degrees_east(3.0), 0, 0, 0, 0], None])
    drive = make_raw(tmp_path / "drive")
    assert open_sequence(drive).gt_poses is None
    gt = open_sequence(drive, ground_truth=other / "oxts").gt_poses
    np.testing.assert_allclose(gt[1][:3, 3], [3.0, 0, 0], atol=1e-6)


# ---------------------------------------------------------------------------------------------
# the real drive

@pytest.mark.realdata
def test_real_drive(shared_data, tmp_path):
    root = shared_data / RAW_DRIVE
    if not root.is_dir():
        pytest.skip(f"{root} not found")
    assert detect_format(root) == "kitti_raw"
    seq = open_sequence(root)
    assert len(seq) == 108 and seq.gt_poses is None
    cam = seq.pinhole
    assert (cam.fx, cam.cx, cam.cy, cam.width, cam.height) == (721.5377, 609.5593, 172.854, 1242, 375)
    assert seq.camera.baseline == pytest.approx(387.5744 / 721.5377)
    assert seq.timestamps[-1] - seq.timestamps[0] == pytest.approx(11.037, abs=0.01)
    assert np.all(np.diff(seq.timestamps) > 0.09)
    assert seq.left(0).shape == (375, 1242) and seq.right(107).shape == (375, 1242)
    # its calibration files: the rectified cam0 sits about 1.08 m ahead of the IMU and 0.73 m above
    # it (KITTI's sensor set-up), looking forward (its z along the IMU's x), its y (down) along -z
    T_cam0_imu = read_rigid(root / "calib_velo_to_cam.txt") @ read_rigid(root / "calib_imu_to_velo.txt")
    T_imu_cam = camera_ground_truth(np.eye(4)[None], T_cam0_imu, read_rectifying_rotation(
        root / "calib_cam_to_cam.txt"), np.zeros(3))[0]
    np.testing.assert_allclose(T_imu_cam[:3, 3], [1.08, -0.31, 0.73], atol=0.01)
    np.testing.assert_allclose(T_imu_cam[:3, 2], [1, 0, 0], atol=0.02)
    np.testing.assert_allclose(T_imu_cam[:3, 1], [0, 0, -1], atol=0.02)
    # KITTI's own layout: calibration in the date folder above the drive
    date = tmp_path / "2011_09_26"
    drive = date / "2011_09_26_drive_0001_sync"
    drive.mkdir(parents=True)
    for cam in ("image_00", "image_01"):
        (drive / cam).symlink_to(root / cam)
    for calib in root.glob("calib_*.txt"):
        shutil.copy(calib, date / calib.name)
    assert detect_format(drive) == "kitti_raw"
    assert open_sequence(drive).camera == seq.camera


@pytest.mark.realdata
@pytest.mark.slow
def test_gtvo_run_detects_the_real_drive(shared_data, tmp_path, capsys):
    from gtvo.cli import main

    root = shared_data / RAW_DRIVE
    if not root.is_dir():
        pytest.skip(f"{root} not found")
    args = ["run", str(root), "--out", str(tmp_path), "--max-frames", "4", "--mode", "track", "--no-progress"]
    assert main(args) == 0
    assert f"gtvo run: {RAW_DRIVE}" in capsys.readouterr().out
    tum = np.loadtxt(tmp_path / "trajectory.tum")
    # 2011-09-26 13:02:25.967790592 read as UTC
    assert tum.shape == (4, 8) and tum[0, 0] == pytest.approx(1317042145.9677906, abs=1e-6)
    assert 0.5 < np.linalg.norm(tum[3, 1:4]) < 10  # a car at about 10-13 m/s over 0.3 s
