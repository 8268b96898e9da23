"""Wheel odometry in: wheel_odometry.csv, --wheel-odometry / --wheel-topic, bag topics and /tf_static,
and the synthetic ground robot that writes them (gtvo.datasets.wheel_files, bag_wheel, synthetic_robot)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gtvo.cli import main as cli_main
from gtvo.config import WheelConfig, load_config
from gtvo.datasets import open_sequence
from gtvo.datasets.bag_wheel import integrate_twists
from gtvo.datasets.identity import sequence_identity
from gtvo.datasets.info import describe_log
from gtvo.datasets.bag_writer import BagWriter, write_sequence_bag
from gtvo.datasets.synthetic import make_synthetic_sequence, synthetic_trajectory, write_sequence_kitti
from gtvo.datasets.synthetic_robot import SYNTHETIC_WHEEL_RADIUS, WheelSimulation, ground_robot_trajectory
from gtvo.datasets.wheel import WheelOdometry, planar_base_poses
from gtvo.datasets.wheel_files import WheelReadOptions, read_wheel_csv, write_wheel_csv
from gtvo.errors import InputError

W, H = 64, 48


def _csv(tmp_path, text: str):
    path = tmp_path / "wheel_odometry.csv"
    path.write_text(text)
    return path


def test_csv_pose_and_arcs_with_tick_scale(tmp_path):
    pose = read_wheel_csv(_csv(tmp_path, "# robot odometry\ntime,x,y,theta\n0.0,0,0,0\n0.1,0.1,0,0.1\n"))
    assert pose.kind == "pose" and pose.values.shape == (2, 3)
    arcs = read_wheel_csv(_csv(tmp_path, "time, left, right\n0,0,0\n0.1,100,120\n"),
                          WheelReadOptions(tick_scale=0.001, nominal_baseline=0.4))
    np.testing.assert_allclose(arcs.values[1], [0.1, 0.12])
    assert arcs.between(0.0, 0.1)[2] == pytest.approx(0.02 / 0.4)


def test_csv_written_reads_back(tmp_path):
    odo = WheelOdometry(np.array([0.0, 0.1, 0.25]), "arcs", np.array([[0, 0], [0.1, 0.11], [1 / 3, 0.4]]), "x", 0.5)
    back = read_wheel_csv(write_wheel_csv(odo, tmp_path / "w.csv"))
    assert np.array_equal(back.times, odo.times) and np.array_equal(back.values, odo.values)


@pytest.mark.parametrize("text, where, message", [
    ("time,x,y\n0,0,0\n", ":1:", "expected time,x,y,theta"),
    ("time,x,y,theta\n0,0,0,0\n0.1,0,nan,0\n", ":3:", "NaN"),
    ("time,x,y,theta\n0,0,0,0\n0.1,0,0,0\n0.1,1,0,0\n", ":4:", "not after"),
    ("time,left,right\n0,0,0\n0.1,0,0\n2.5,1,1\n", ":4:", "a gap of 2.4 s"),
    ("time,left,right\n0,0,0\n0.1,0,0,7\n", ":3:", "expected 3 values"),
    ("time,left,right\n0,0,0\n", ": wheel", "at least 2 readings"),
    ("time,left,right\n0,0,0\n0.1,100,120\n", ":3:", "a wheel moved 120 m in 0.1 s .*wheel.tick_scale"),
    ("time,x,y,theta\n0,0,0,0\n0.1,150,0,0\n", ":3:", "the base moved 150 m .*metres"),
])
def test_bad_csv_is_one_line_naming_file_and_row(tmp_path, text, where, message):
    path = _csv(tmp_path, text)
    with pytest.raises(InputError, match=message) as err:
        read_wheel_csv(path)
    assert f"{path}{where}" in str(err.value) and "\n" not in str(err.value)


@pytest.fixture(scope="module")
def robot_folder(tmp_path_factory):
    """A short synthetic ground-robot log in the KITTI layout with its wheel arcs."""
    seq = make_synthetic_sequence(8, W, H, motion="ground", wheels=WheelSimulation(calibration=(1.02, 0.98, 1.04)))
    return seq, write_sequence_kitti(seq, tmp_path_factory.mktemp("robot") / "seq")


def test_wheel_yaml_names_the_model_of_the_simulated_calibration(tmp_path):
    """A linear X simulated: wheel.yaml asks for the linear model (the diff-drive one cannot recover it)."""
    x = (1.02, 0.0, 0.01, 0.0, 0.99, 0.0, 0.0, 0.0, 0.97)
    seq = make_synthetic_sequence(3, W, H, motion="ground", wheels=WheelSimulation(kind="pose", calibration=x))
    config = load_config(write_sequence_kitti(seq, tmp_path / "seq") / "wheel.yaml")
    assert config.wheel.model == "linear"


def test_folder_reads_its_wheel_csv_and_wheel_yaml(robot_folder, tmp_path):
    seq, folder = robot_folder
    config = load_config(folder / "wheel.yaml")
    assert config.wheel.model == "diff_drive"
    np.testing.assert_allclose(config.wheel.T_base_cam, seq.wheel_odometry.base_to_camera, atol=1e-12)
    read = open_sequence(folder, wheel_options=config.wheel.read_options())
    assert read.wheel_odometry.kind == "arcs" and read.wheel_odometry.source.endswith("wheel_odometry.csv")
    np.testing.assert_array_equal(read.wheel_odometry.values, seq.wheel_odometry.values)
    assert open_sequence(folder, wheel_odometry=_csv(tmp_path, "time,x,y,theta\n0,0,0,0\n1,1,0,0\n")
                         ).wheel_odometry.kind == "pose"  # --wheel-odometry FILE wins
    with pytest.raises(InputError, match="wheel_topic apply to ROS bags only"):
        open_sequence(folder, wheel_topic="/odom")


def test_the_input_identity_covers_the_wheels(robot_folder, tmp_path):
    seq, folder = robot_folder
    plain = open_sequence(folder, wheel_topic=None, wheel_options=None)
    other = open_sequence(folder, wheel_odometry=_csv(tmp_path, "time,x,y,theta\n0,0,0,0\n1,1,0,0\n"))
    ids = {sequence_identity(s)["sha256"] for s in (plain, other)}
    plain.wheel_odometry = None
    ids.add(sequence_identity(plain)["sha256"])
    assert len(ids) == 3


def test_cli_run_refuses_a_bad_wheel_file_in_one_line(robot_folder, tmp_path, capsys):
    _, folder = robot_folder
    bad = _csv(tmp_path, "time,x,y,theta\n0,0,0,0\n0.2,0,0,0\n0.1,0,0,0\n")
    code = cli_main(["run", str(folder), "--out", str(tmp_path / "out"), "--wheel-odometry", str(bad),
                     "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0 and f"{bad}:4: time 0.1 s is not after" in err


def test_wheel_times_in_another_clock_are_refused_and_a_partial_log_warned(robot_folder, tmp_path, capsys):
    """A wheel log that overlaps none of the frames (its times in another clock) stops the run in
    one line, writing nothing; one that covers only some frames is a warning naming how many."""
    from gtvo.odometry.wheel import wheel_coverage_warning

    _, folder = robot_folder
    late = _csv(tmp_path, "time,x,y,theta\n1000,0,0,0\n1000.5,0.1,0,0\n")
    code = cli_main(["run", str(folder), "--out", str(tmp_path / "out"), "--wheel-odometry", str(late),
                     "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0 and not (tmp_path / "out").exists()
    assert f"{late}: the wheel odometry's times 1000.000..1000.500 s do not overlap the frames' 0.000..0.700 s" in err
    log = WheelOdometry(np.array([0.0, 0.35]), "pose", np.zeros((2, 3)), "w.csv")
    assert "covers 0.000..0.350 s, 4 of the 8 frames" in wheel_coverage_warning(log, np.arange(8) / 10)
    assert wheel_coverage_warning(log, [0.1, 0.3]) is None


def test_ground_robot_is_level_turns_both_ways_and_runs_300_frames():
    T = ground_robot_trajectory(320)
    assert np.abs(T[:, 1, 3]).max() < 1e-9 and np.abs(T[:, :3, 1] - [0, 1, 0]).max() < 1e-9  # level, y down
    np.testing.assert_allclose(T[0], np.eye(4), atol=1e-12)
    base = planar_base_poses(T, WheelSimulation().T_base_cam)
    turn = np.diff(base[:, 2])
    assert turn.max() > 0.02 and turn.min() < -0.02  # left and right turns
    np.testing.assert_allclose(synthetic_trajectory(320, "ground"), T)


def test_synthetic_bag_carries_odometry_joint_states_and_tf_static(tmp_path):
    wheels = WheelSimulation(calibration=(1.03, 0.98, 1.05), noise=0.0005, seed=3)
    seq = make_synthetic_sequence(10, W, H, motion="ground", wheels=wheels)
    bag = write_sequence_bag(seq, tmp_path / "robot.bag")
    read = open_sequence(bag, ground_truth_topic="/ground_truth")  # /odom: the one candidate
    odo, truth = read.wheel_odometry, seq.wheel_odometry.as_kind("pose")
    assert odo.source.endswith(":/odom") and odo.kind == "pose"
    np.testing.assert_allclose(odo.base_to_camera, wheels.T_base_cam, atol=1e-12)  # from /tf_static
    np.testing.assert_allclose(odo.values, truth.values, atol=1e-9)
    np.testing.assert_allclose(odo.times - 1.0, truth.times, atol=1e-9)  # the bag starts at 1 s
    options = WheelConfig(wheel_radius=SYNTHETIC_WHEEL_RADIUS).read_options()
    with pytest.raises(InputError, match="2 wheel odometry topics .*--wheel-topic"):
        open_sequence(bag, wheel_options=options)
    joints = open_sequence(bag, wheel_topic="/joint_states", wheel_options=options).wheel_odometry
    np.testing.assert_allclose(joints.values, seq.wheel_odometry.values, atol=1e-12)
    assert open_sequence(bag, wheel_topic="none").wheel_odometry is None
    assert f"  wheels       {bag}:/odom: pose, 10 readings over 1.000..1.900 s" in describe_log(bag).lines()
    with pytest.raises(InputError, match="--wheel-topic /cam/left/image_rect is sensor_msgs/msg/Image"):
        open_sequence(bag, wheel_topic="/cam/left/image_rect")
    with pytest.raises(InputError, match="wheel radius"):
        open_sequence(bag, wheel_topic="/joint_states")
    with pytest.raises(InputError, match=r"/joint_states: message 2: a wheel moved .* wheel.max_speed 50 m/s"):
        open_sequence(bag, wheel_topic="/joint_states", wheel_options=dataclasses.replace(options, wheel_radius=100.0))


def _tiny_stereo_bag(path, times, write_more):
    """A bag of blank rectified stereo frames at ``times`` (+1 s) and CameraInfo; ``write_more(bag, k, ns)``
    adds the messages under test."""
    K = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
    with BagWriter(path) as bag:
        for side, tx in (("left", 0.0), ("right", -5.0)):
            bag.camera_info(f"/cam/{side}/camera_info", int(1e9), W, H, K, np.hstack([K, [[tx], [0], [0]]]))
        for k, t in enumerate(times):
            ns = int(round((1 + t) * 1e9))
            for side in ("left", "right"):
                bag.image(f"/cam/{side}/image_rect", ns, np.zeros((H, W), np.uint8), "mono8", frame_id="cam_optical")
            write_more(bag, k, ns)
    return path


def test_twist_only_odometry_and_twist_stamped_are_integrated(tmp_path):
    times = np.arange(30) * 0.05
    twists = np.column_stack([np.full(30, 0.8), np.zeros(30), 0.6 * np.sin(times)])
    poses = integrate_twists(times, twists)
    np.testing.assert_allclose(poses[1], [0.8 * 0.05, 0, 0], atol=1e-12)

    def more(bag, k, ns):
        bag.odometry("/odom", ns, np.zeros(3), twists[k])  # a driver that publishes only its twist
        bag.write("/vel", "geometry_msgs/msg/TwistStamped", ns, bag._make(
            "geometry_msgs/msg/TwistStamped", header=bag.header(ns), twist=bag._make(
                "geometry_msgs/msg/Twist", linear=bag._vector(*twists[k, :2], 0.0),
                angular=bag._vector(0, 0, twists[k, 2]))))

    path = _tiny_stereo_bag(tmp_path / "t.bag", times, more)
    for topic in ("/odom", "/vel"):
        odo = open_sequence(path, wheel_topic=topic).wheel_odometry
        np.testing.assert_allclose(odo.values, poses, atol=1e-12)
        assert ("twist integrated" in odo.source) == (topic == "/odom")
    with pytest.raises(InputError, match="2 wheel odometry topics"):
        open_sequence(path)


def test_joint_states_by_name_and_tf_static_through_a_chain(tmp_path):
    T_base_mount, T_mount_cam = np.eye(4), WheelConfig().T_base_cam
    T_base_mount[:3, 3] = [0.2, 0.0, 0.5]

    def more(bag, k, ns):
        if k == 0:
            bag.tf_static(ns, [("base_link", "mount", T_base_mount), ("cam_optical", "mount",
                                                                        np.linalg.inv(T_mount_cam))])
        names = ["arm", "right_wheel", "left_wheel"] if k % 2 else ["left_wheel", "right_wheel"]
        positions = [0.0, 2.0 * k, 1.0 * k] if k % 2 else [1.0 * k, 2.0 * k]
        if k == 4:
            names, positions = ["left_wheel"], [4.0]
        bag.joint_state("/joint_states", ns, names, positions)

    options = WheelConfig(wheel_radius=0.05).read_options()
    with pytest.raises(InputError, match=r"/joint_states: message 5: no position of joint 'left_wheel' and "):
        open_sequence(_tiny_stereo_bag(tmp_path / "bad.bag", np.arange(6) * 0.1, more), wheel_options=options)
    path = _tiny_stereo_bag(tmp_path / "j.bag", np.arange(4) * 0.1, more)
    odo = open_sequence(path, wheel_options=options).wheel_odometry
    np.testing.assert_allclose(odo.values, 0.05 * np.arange(4)[:, None] * [1.0, 2.0])
    np.testing.assert_allclose(odo.base_to_camera, T_base_mount @ T_mount_cam, atol=1e-12)


def test_synthetic_cli_writes_wheels_and_refuses_bad_calibration(tmp_path, capsys):
    out = tmp_path / "robot"
    assert cli_main(["synthetic", "--out", str(out), "--frames", "4", "--width", "64", "--height", "48",
                     "--motion", "ground", "--wheel", "pose", "--wheel-calibration", "1,0,0,0,1,0,0,0,1.02",
                     "--no-progress"]) == 0
    assert read_wheel_csv(out / "wheel_odometry.csv").kind == "pose"
    capsys.readouterr()
    assert cli_main(["synthetic", "--out", str(tmp_path / "x"), "--wheel", "arcs", "--wheel-calibration", "1,2",
                     "--no-progress"]) == 2
    assert "--wheel-calibration" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["--wheel", "pose", "--wheel-calibration", "0,0,0,0,0,0,0,0,0"], "X must be invertible"),
    (["--wheel", "pose", "--wheel-calibration", "1,2"], "must be 3 numbers (k_L,k_R,k_b) or 9 (X row-major)"),
    (["--wheel-noise", "0.01"], "--wheel-noise describe the wheel odometry: add --wheel arcs or --wheel pose"),
])
def test_synthetic_cli_refuses_bad_wheel_options_in_one_line(tmp_path, capsys, argv, message):
    """A singular X, a calibration of neither 3 nor 9 numbers, wheel options without --wheel: exit 2,
    one line, nothing written."""
    out = tmp_path / "x"
    assert cli_main(["synthetic", "--out", str(out), "--frames", "2", "--width", "64", "--height", "48",
                     "--motion", "ground", *argv, "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and err.count("\n") == 0 and not out.exists()
