"""IMU files beside a sequence (gtvo.datasets.imu_files, gtvo.datasets.bag_imu): EuRoC, Kalibr,
plain CSV, a bag's sensor_msgs/Imu, the config's imu: section and --no-imu."""

from __future__ import annotations

import numpy as np
import pytest

from gtvo.cli import main as cli_main
from gtvo.config import ImuConfig
from gtvo.datasets import open_sequence
from gtvo.datasets.bag_writer import BagWriter, write_sequence_bag
from gtvo.datasets.imu_files import ImuReadOptions, imu_read_options, read_imu_folder, read_imu_table
from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti
from gtvo.datasets.synthetic_imu import SYNTHETIC_T_CAM_IMU, ImuSimulation
from gtvo.errors import InputError

T_CAM_IMU = [[0, -1, 0, 0.1], [0, 0, -1, 0.0], [1, 0, 0, -0.2], [0, 0, 0, 1]]


def _plain_csv(path, n=60, rate=100.0, start=0.0):
    t = start + np.arange(n) / rate
    rows = [f"{x:.6f},0.01,0.02,0.03,0.1,0.2,9.8" for x in t]
    path.write_text("time,wx,wy,wz,ax,ay,az\n" + "\n".join(rows) + "\n")
    return path


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A 6-frame synthetic log with its IMU (imu0/ beside the images)."""
    out = tmp_path_factory.mktemp("imu") / "log"
    seq = make_synthetic_sequence(6, 64, 48, motion="forward", imu=ImuSimulation(rate_hz=200.0))
    write_sequence_kitti(seq, out)
    return out, seq


def test_the_written_folder_reads_back_exactly(folder):
    out, seq = folder
    imu = open_sequence(out).imu
    assert imu is not None and len(imu) == len(seq.imu)
    np.testing.assert_allclose(imu.times, seq.imu.times, atol=1e-9)
    np.testing.assert_array_equal(imu.gyro, seq.imu.gyro)
    np.testing.assert_array_equal(imu.accel, seq.imu.accel)
    np.testing.assert_array_equal(imu.T_cam_imu, SYNTHETIC_T_CAM_IMU)
    assert imu.noise.gyro_noise_density == seq.imu.noise.gyro_noise_density
    assert open_sequence(out, imu_options=imu_read_options(ImuConfig(enabled=False))).imu is None


def test_kalibr_files_beside_the_log_give_extrinsic_noise_and_time_shift(folder, tmp_path):
    out, seq = folder
    (out / "log-camchain-imucam.yaml").write_text(
        f"cam0:\n  T_cam_imu:\n" + "".join(f"  - {row}\n" for row in T_CAM_IMU) + "  timeshift_cam_imu: 0.004\n")
    (out / "log-imu.yaml").write_text("imu0:\n  accelerometer_noise_density: 0.01\n  accelerometer_random_walk: 0.0002\n"
                                      "  gyroscope_noise_density: 0.001\n  gyroscope_random_walk: 4.0e-06\n"
                                      "  update_rate: 200.0\n  rostopic: /imu0\n")
    try:
        imu = open_sequence(out).imu
    finally:
        (out / "log-camchain-imucam.yaml").unlink()
        (out / "log-imu.yaml").unlink()
    np.testing.assert_array_equal(imu.T_cam_imu, np.array(T_CAM_IMU, dtype=float))
    assert imu.time_shift == 0.004 and "camchain" in imu.extrinsic_source
    np.testing.assert_allclose(imu.times, seq.imu.times - 0.004, atol=1e-9)
    assert (imu.noise.gyro_noise_density, imu.noise.accel_random_walk) == (0.001, 0.0002)


def test_plain_csv_needs_an_extrinsic_from_somewhere(tmp_path, folder):
    out, _ = folder
    csv = _plain_csv(tmp_path / "imu.csv")
    times, gyro, accel = read_imu_table(csv)
    assert times[1] == pytest.approx(0.01) and gyro[0, 2] == 0.03 and accel[0, 2] == 9.8
    with pytest.raises(InputError, match="imu.csv: the IMU's pose on the camera is not given"):
        open_sequence(out, imu=csv)
    options = imu_read_options(ImuConfig(imu_in_camera=(0.1, 0, 0, 0, 0, 0, 1), gyro_noise_density=1e-3,
                                         accel_noise_density=1e-2, gyro_random_walk=1e-5, accel_random_walk=1e-3))
    imu = open_sequence(out, imu=csv, imu_options=options).imu
    assert imu.T_cam_imu[0, 3] == 0.1 and imu.extrinsic_source == "config imu.T_cam_imu"
    assert imu.noise.source == "config imu:" and imu.noise.accel_noise_density == 1e-2
    with pytest.raises(InputError, match="--imu and --no-imu"):
        open_sequence(out, imu=csv, imu_options=ImuReadOptions(enabled=False))
    with pytest.raises(InputError, match="imu_topic apply to ROS bags only"):
        open_sequence(out, imu_topic="/imu")


@pytest.mark.parametrize("body, line, message", [
    ("time,wx,wy,wz\n0,1,2,3\n", 1, "the header is"),
    ("time,wx,wy,wz,ax,ay,az\n0,0,0,0,0,0,9.8\n0.01,0,0,0,0,0\n", 3, "expected 7 values"),
    ("time,wx,wy,wz,ax,ay,az\n0,0,0,0,0,0,9.8\n0.01,0,0,x,0,0,9.8\n", 3, "not a number: 'x'"),
    ("time,wx,wy,wz,ax,ay,az\n" + "".join(f"{k / 100},0,0,0,0,0,9.8\n" for k in range(5)) + "0.05,nan,0,0,0,0,9.8\n",
     7, "not a finite IMU reading"),
    ("time,wx,wy,wz,ax,ay,az\n" + "".join(f"{k / 100},0,0,0,0,0,9.8\n" for k in range(5)) + "0.5,0,0,0,0,0,9.8\n",
     7, "a gap of 0.46 s"),
    ("time,wx,wy,wz,ax,ay,az\n" + "".join(f"{k / 100},0,0,{k * 10},0,0,9.8\n" for k in range(6)), 6,
     "degrees per second"),
    ("time,wx,wy,wz,ax,ay,az\n" + "".join(f"{k / 100},0,0,0,0,0,1.0\n" for k in range(6)), 2, "in g\\?"),
    ("time,wx,wy,wz,ax,ay,az\n" + "".join(f"{k / 10},0,0,0,0,0,9.8\n" for k in range(6)), 3, "rate is 10 Hz"),
    ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],"
     "a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n1000,0,0,0,0,0,9.8\n1.5e3,0,0,0,0,0,9.8\n", 3, "not an integer nanosecond"),
])
def test_bad_csv_is_one_line_naming_file_and_line(tmp_path, body, line, message):
    csv = tmp_path / "imu.csv"
    csv.write_text(body)
    with pytest.raises(InputError, match=message) as err:
        read_imu_table(csv)
    assert str(err.value).startswith(f"{csv}:{line}: ") and "\n" not in str(err.value)


def test_images_and_imu_in_other_clocks_are_refused(tmp_path, folder):
    out, _ = folder
    csv = _plain_csv(tmp_path / "imu.csv", start=1.7e9)
    options = imu_read_options(ImuConfig(imu_in_camera=(0, 0, 0, 0, 0, 0, 1)))
    with pytest.raises(InputError, match="another clock"):
        open_sequence(out, imu=csv, imu_options=options)


def test_euroc_sensor_yaml_with_a_repeated_key_keeps_the_last(tmp_path):
    (tmp_path / "imu0").mkdir()
    _plain_csv(tmp_path / "imu0" / "data.csv")
    (tmp_path / "imu0" / "sensor.yaml").write_text(
        "%YAML:1.0\nsensor_type: imu\nT_BS:\n  cols: 4\n  rows: 4\n  data: [1.0, 0.0, 0.0, 0.5, 0.0, 1.0, 0.0, 0.0, "
        "0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]\ngyroscope_noise_density: 1.0e-4\ngyroscope_noise_density: 2.0e-4\n"
        "gyroscope_random_walk: 1.0e-5\naccelerometer_noise_density: 2.0e-3\naccelerometer_random_walk: 3.0e-3\n")
    imu = read_imu_folder(tmp_path, ImuReadOptions())
    assert imu.noise.gyro_noise_density == 2.0e-4 and imu.T_cam_imu[0, 3] == 0.5


@pytest.mark.realdata
def test_real_euroc_imu_gives_gravity_within_a_degree_of_the_ground_truth(shared_data):
    root = shared_data / "euroc_v101_static_stereo"
    seq = open_sequence(root)
    imu = seq.imu
    assert imu is not None and len(imu) == 211 and imu.rate_hz == pytest.approx(200.0, rel=1e-3)
    assert imu.noise.gyro_noise_density == 1.6968e-04 and imu.noise.accel_random_walk == 3.0e-3
    up = seq.gt_poses[0][:3, :3] @ imu.T_cam_imu[:3, :3] @ imu.accel.mean(axis=0)  # the static IMU reads "up"
    assert np.degrees(np.arccos(up[2] / np.linalg.norm(up))) < 1.0  # EuRoC's world: z up
    assert open_sequence(root, imu_options=ImuReadOptions(enabled=False)).imu is None


@pytest.mark.slow
def test_bag_imu_topic_with_its_tf_static_and_the_choice_of_topics(tmp_path):
    seq = make_synthetic_sequence(4, 64, 48, motion="forward", imu=ImuSimulation(rate_hz=100.0))
    path = write_sequence_bag(seq, tmp_path / "log.bag")
    imu = open_sequence(path).imu
    np.testing.assert_allclose(imu.T_cam_imu, SYNTHETIC_T_CAM_IMU, atol=1e-12)
    assert imu.extrinsic_source.endswith("/tf_static") and imu.source.endswith(":/imu")
    np.testing.assert_allclose(imu.gyro, seq.imu.gyro)
    np.testing.assert_allclose(imu.times - imu.times[0], seq.imu.times - seq.imu.times[0], atol=1e-8)
    assert open_sequence(path, imu_topic="none").imu is None
    with pytest.raises(InputError, match="--imu-topic /nope is not in the bag; sensor_msgs/Imu topics: /imu"):
        open_sequence(path, imu_topic="/nope")
    ros2 = open_sequence(write_sequence_bag(seq, tmp_path / "ros2")).imu  # a ROS2 bag folder alike
    np.testing.assert_allclose(ros2.accel, seq.imu.accel)
    np.testing.assert_allclose(ros2.T_cam_imu, SYNTHETIC_T_CAM_IMU, atol=1e-12)


def test_a_bag_with_a_bad_imu_message_names_it(tmp_path):
    K = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
    path = tmp_path / "bad.bag"
    with BagWriter(path) as bag:
        for side, tx in (("left", 0.0), ("right", -5.0)):
            bag.camera_info(f"/cam/{side}/camera_info", int(1e9), 64, 48, K, np.hstack([K, [[tx], [0], [0]]]))
        for k in range(3):
            ns = int(1e9) + k * 100_000_000
            for side in ("left", "right"):
                bag.image(f"/cam/{side}/image_rect", ns, np.zeros((48, 64), np.uint8), "mono8", frame_id="cam")
        for k in range(40):
            bag.imu("/imu", int(1e9) + k * 5_000_000, [0, 0, 0], [0, 0, np.nan if k == 12 else 9.8])
    with pytest.raises(InputError, match=r"bad.bag:/imu: message 13: not a finite IMU reading"):
        open_sequence(path)


def test_cli_run_no_imu_and_a_bad_imu_file(folder, tmp_path, capsys):
    out, _ = folder
    bad = tmp_path / "imu.csv"
    bad.write_text("time,wx,wy,wz,ax,ay,az\n0,0,0,0,0,0,nan\n")
    assert cli_main(["run", str(out), "--imu", str(bad), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"{bad}:" in err
    assert cli_main(["run", str(out), "--imu", str(bad), "--no-imu", "--out", str(tmp_path / "o"),
                     "--no-progress"]) == 2
    assert "--imu and --no-imu" in capsys.readouterr().err


def test_info_lists_the_imu_with_its_rate_count_and_file(folder, capsys):
    out, seq = folder
    assert cli_main(["info", str(out)]) == 0
    line = [x for x in capsys.readouterr().out.splitlines() if x.strip().startswith("imu ")]
    assert len(line) == 1 and "imu0/data.csv" in line[0] and f"{len(seq.imu)} readings at 200 Hz" in line[0]
    assert "T_cam_imu " in line[0] and "noise " in line[0]
