"""ROS bags in (gtvo.datasets.bag, bag_calib, info; gtvo run / gtvo info on bags).

The real-data tests write ROS1 and ROS2 bags from KITTI_sequence_1 and the TUM teddy clip with
``rosbags``' writers into a temporary folder and check that a run on the bag gives the run on the
folder to the bit. The other tests build tiny synthetic bags.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from gtvo.cli import main as cli_main
from gtvo.datasets import open_sequence
from gtvo.datasets.bag_stream import BagStream, decode_image, depth_metres
from gtvo.datasets.bag_topics import TopicSummary, choose_topics
from gtvo.errors import InputError
from tests._bags import BagWriter, stamp_from_text

pytest.importorskip("rosbags")

FRAMES = 8
W, H = 64, 48
K_SMALL = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])


# --------------------------------------------------------------------------------------------
# tiny synthetic bags

def _texture(i: int, shape: tuple[int, int] = (H, W)) -> np.ndarray:
    rng = np.random.default_rng(i)
    return rng.integers(0, 256, size=shape, dtype=np.uint8)


def _P(K: np.ndarray, tx: float = 0.0) -> np.ndarray:
    P = np.hstack([K, np.zeros((3, 1))])
    P[0, 3] = tx
    return P


def write_small_stereo(path: Path, n: int = 5, right_offset_ns: int = 0, drop_right: tuple[int, ...] = (),
                       encoding: str = "mono8", info: bool = True, zero_info: bool = False,
                       D: np.ndarray | None = None, R: np.ndarray | None = None, gt: str | None = None,
                       image_topic: str = "image_rect", mcap: bool = False) -> Path:
    """A small stereo bag: /cam/{left,right}/<image_topic> (+ camera_info, + /gt poses)."""
    with BagWriter(path, mcap=mcap) as bag:
        for i in range(n):
            ns = 1_000_000_000 + i * 100_000_000
            if i == 0 and info:
                for side, tx in (("left", 0.0), ("right", -50.0 * 0.1)):
                    K = np.zeros((3, 3)) if zero_info else K_SMALL
                    bag.camera_info(f"/cam/{side}/camera_info", ns, W, H, K, _P(K, tx if not zero_info else 0.0),
                                    D=D, R=R)
            bag.image(f"/cam/left/{image_topic}", ns, _texture(2 * i), encoding)
            if i not in drop_right:
                bag.image(f"/cam/right/{image_topic}", ns + right_offset_ns, _texture(2 * i + 1), encoding)
            if gt is not None:
                T = np.eye(4)
                T[:3, 3] = [0.1 * i, 0.0, 0.2 * i]
                T[:3, :3] = cv2.Rodrigues(np.array([0.0, 0.05 * i, 0.0]))[0]
                bag.pose("/gt", ns, T, gt)
    return path


def _run_cli(args: list[str], capsys) -> tuple[int, str, str]:
    code = cli_main(args)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
def test_small_stereo_bag_ros1_ros2_mcap(tmp_path):
    seqs = [open_sequence(write_small_stereo(tmp_path / name, mcap=mcap))
            for name, mcap in (("a.bag", False), ("b", False), ("c", True))]
    for seq in seqs:
        assert seq.kind == "stereo" and len(seq) == 5
        assert seq.camera.baseline == pytest.approx(0.1)
        assert seq.timestamps[3] == 1.3  # header stamp 1 s + 300000000 ns
        for i in (0, 3, 4):
            np.testing.assert_array_equal(seq.left(i), _texture(2 * i).astype(np.float32))
            np.testing.assert_array_equal(seq.right(i), _texture(2 * i + 1).astype(np.float32))


def test_streaming_reads_the_bag_once_in_order_and_jumps_back(tmp_path):
    seq = open_sequence(write_small_stereo(tmp_path / "a.bag", n=40))
    stream: BagStream = seq.load_left.stream
    restarts = []
    original = stream._restart
    stream._restart = lambda start: (restarts.append(start), original(start))[1]
    for frame in seq:
        np.testing.assert_array_equal(frame.right, _texture(2 * frame.index + 1).astype(np.float32))
    assert len(restarts) == 1  # one pass over the bag for a run
    assert len(stream._buffer) <= 1
    np.testing.assert_array_equal(seq.left(3), _texture(6).astype(np.float32))  # back: restart
    assert len(restarts) == 2
    np.testing.assert_array_equal(seq.right(3), _texture(7).astype(np.float32))  # its partner: no restart
    assert len(restarts) == 2


def test_pairing_counts_unpaired_and_max_frames(tmp_path):
    path = write_small_stereo(tmp_path / "a.bag", n=6, drop_right=(2,), right_offset_ns=2_000_000)
    seq = open_sequence(path)
    assert len(seq) == 5 and seq.unpaired == {"/cam/left/image_rect": 1, "/cam/right/image_rect": 0}
    np.testing.assert_array_equal(seq.left(2), _texture(6).astype(np.float32))  # frame 2 is left message 3
    np.testing.assert_array_equal(seq.right(2), _texture(7).astype(np.float32))
    assert len(open_sequence(path, max_frames=2)) == 2
    unstamped = tmp_path / "zero.bag"
    with BagWriter(unstamped) as bag:
        for i in range(4):
            bag.image("/cam/left/image_rect", 0, _texture(i), "mono8", log_ns=10**9 + i)
            bag.image("/cam/right/image_rect", 0, _texture(i), "mono8", log_ns=10**9 + i)
    with pytest.raises(InputError, match="4 messages carry only 1 distinct header stamps"):
        open_sequence(unstamped)
    with pytest.raises(InputError, match="never pair within 1 ms"):
        open_sequence(path, stamp_tolerance=0.001)


def test_right_camera_dropping_images_is_one_warning_line(tmp_path, capsys):
    from gtvo.datasets.synthetic import make_synthetic_sequence

    seq = make_synthetic_sequence(n_frames=16, width=160, height=120, seed=1)
    K = seq.camera.left.K
    paths = []
    for name, dropped in (("a.bag", range(4, 14)), ("b.bag", ())):  # the right camera drops 10 images, or none
        with BagWriter(tmp_path / name) as bag:
            for i in range(len(seq)):
                ns = 1_000_000_000 + i * 100_000_000
                if i == 0:
                    for side, tx in (("left", 0.0), ("right", -K[0, 0] * seq.camera.baseline)):
                        bag.camera_info(f"/cam/{side}/camera_info", ns, 160, 120, K, _P(K, tx))
                for side, image in (("left", seq.left(i)), ("right", seq.right(i))):
                    if side == "left" or i not in dropped:
                        bag.image(f"/cam/{side}/image_rect", ns, np.clip(np.rint(image), 0, 255).astype(np.uint8),
                                  "mono8")
        paths.append(tmp_path / name)
    code, out, err = _run_cli(["run", str(paths[0]), "--out", str(tmp_path / "out"), "--no-progress",
                               "--mode", "track"], capsys)
    assert code == 0, err
    warnings = [line for line in err.splitlines() if line.startswith("warning:")]
    assert warnings == [f"warning: {paths[0]}: 10 /cam/left/image_rect messages without a /cam/right/image_rect "
                        "partner: those frames are left out (a camera dropped images, or --stamp-tolerance is too "
                        "tight; unpaired_messages in report.json)"], err
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["frames"] == 6 and report["unpaired_messages"] == {"/cam/left/image_rect": 10,
                                                                     "/cam/right/image_rect": 0}
    code, out, err = _run_cli(["run", str(paths[1]), "--out", str(tmp_path / "o2"), "--no-progress", "--mode", "track"],
                              capsys)
    assert code == 0 and "warning" not in err, err  # every message paired: no word


def test_raw_camera_info_is_rectified_with_its_own_K_D_R_P(tmp_path):
    D = np.array([-0.1, 0.02, 0.001, -0.001, 0.0])
    R = cv2.Rodrigues(np.array([0.0, 0.02, 0.0]))[0]
    seq = open_sequence(write_small_stereo(tmp_path / "a.bag", image_topic="image_raw", D=D, R=R,
                                           gt="geometry_msgs/msg/PoseStamped"), ground_truth_topic="/gt")
    maps = cv2.initUndistortRectifyMap(K_SMALL, D, R, _P(K_SMALL), (W, H), cv2.CV_32FC1)
    expected = cv2.remap(_texture(2).astype(np.float32), maps[0], maps[1], cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    np.testing.assert_array_equal(seq.left(1), expected)
    raw = open_sequence(write_small_stereo(tmp_path / "b.bag", image_topic="image_raw",
                                           gt="geometry_msgs/msg/PoseStamped"), ground_truth_topic="/gt")
    T_raw_rect = np.eye(4)
    T_raw_rect[:3, :3] = R.T
    np.testing.assert_allclose(seq.gt_poses, raw.gt_poses @ T_raw_rect, atol=1e-12)


@pytest.mark.parametrize("D, R, message", [
    (np.array([0.1, 0.0, 0.0]), None, "D has 3 coefficients"),
    (np.full(6, 0.01), None, "D has 6 coefficients"),
    (np.array([0.1, 0, 0, 0, 0]), np.zeros((3, 3)), "R is not a rotation"),
    (np.array([0.1, 0, 0, 0, 0]), np.diag([1.0, 1.0, -1.0]), "R is not a rotation"),
])
def test_raw_camera_info_opencv_cannot_rectify_is_one_line(tmp_path, capsys, D, R, message):
    path = write_small_stereo(tmp_path / "a.bag", image_topic="image_raw", D=D, R=R)
    code, out, err = _run_cli(["run", str(path), "--out", str(tmp_path / "out"), "--no-progress"], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"{path}: /cam/left/camera_info: camera calibration {message}" in lines[0], err
    rectified = write_small_stereo(tmp_path / "b.bag", image_topic="image_rect", D=D, R=R)
    assert len(open_sequence(rectified)) == 5  # rectified images: D and R are not used


@pytest.mark.parametrize("msgtype", ["nav_msgs/msg/Odometry", "geometry_msgs/msg/TransformStamped"])
def test_ground_truth_topic_types_agree(tmp_path, msgtype):
    ref = open_sequence(write_small_stereo(tmp_path / "p.bag", gt="geometry_msgs/msg/PoseStamped"),
                        ground_truth_topic="/gt")
    seq = open_sequence(write_small_stereo(tmp_path / "o.bag", gt=msgtype), ground_truth_topic="/gt")
    assert seq.has_ground_truth
    np.testing.assert_allclose(seq.gt_poses, ref.gt_poses, atol=1e-12)
    np.testing.assert_allclose(ref.gt_poses[2][:3, 3], [0.2, 0.0, 0.4], atol=1e-12)


def test_ground_truth_file_for_a_bag(tmp_path):
    from scipy.spatial.transform import Rotation

    ref = open_sequence(write_small_stereo(tmp_path / "p.bag", gt="geometry_msgs/msg/PoseStamped"),
                        ground_truth_topic="/gt")
    rows = [" ".join(f"{float(v)!r}" for v in [t, *T[:3, 3], *Rotation.from_matrix(T[:3, :3]).as_quat()])
            for t, T in zip(ref.timestamps, ref.gt_poses)]
    (tmp_path / "gt.txt").write_text("\n".join(rows) + "\n")
    seq = open_sequence(tmp_path / "p.bag", ground_truth=tmp_path / "gt.txt")
    np.testing.assert_allclose(seq.gt_poses, ref.gt_poses, atol=1e-12)
    late = tmp_path / "late.txt"
    late.write_text("".join(f"{100.0 + k} 0 0 0 0 0 0 1\n" for k in range(3)))
    with pytest.raises(InputError, match="does not overlap"):
        open_sequence(tmp_path / "p.bag", ground_truth=late)


def test_calib_files_replace_camera_info(tmp_path):
    bag = write_small_stereo(tmp_path / "a.bag", info=False)
    with pytest.raises(InputError, match="--calib"):
        open_sequence(bag)
    kitti = tmp_path / "calib.txt"
    kitti.write_text("".join(f"P{k}: " + " ".join(f"{v:.12e}" for v in _P(K_SMALL, tx).reshape(-1)) + "\n"
                             for k, tx in ((0, 0.0), (1, -5.0))))
    yaml_file = tmp_path / "stereo.yaml"
    block = lambda tx: (f"  image_width: {W}\n  image_height: {H}\n"  # noqa: E731
                        f"  projection_matrix: {{rows: 3, cols: 4, data: {_P(K_SMALL, tx).reshape(-1).tolist()}}}\n")
    yaml_file.write_text("left:\n" + block(0.0) + "right:\n" + block(-5.0))
    with_info = open_sequence(write_small_stereo(tmp_path / "b.bag"))
    for calib in (kitti, yaml_file):
        seq = open_sequence(bag, calib=calib)
        assert seq.camera == with_info.camera
        np.testing.assert_array_equal(seq.left(1), with_info.left(1))
    bad = tmp_path / "bad.yaml"
    bad.write_text("left:\n" + block(0.0) + "  distortion_coefficients: [a, b]\nright:\n" + block(-5.0))
    with pytest.raises(InputError, match="bad.yaml: left: distortion_coefficients must be a list of numbers"):
        open_sequence(bag, calib=bad)
    (tmp_path / "none.yaml").write_text("cameras: 2\n")
    with pytest.raises(InputError, match="none.yaml: calibration yaml needs 'left:'"):
        open_sequence(bag, calib=tmp_path / "none.yaml")


def test_decode_image_encodings():
    gray = _texture(0)
    bgr = np.stack([_texture(1), _texture(2), _texture(3)], axis=-1)
    g16 = (gray.astype(np.uint16) * 257)

    def msg(arr: np.ndarray, encoding: str, big: bool = False):
        data = arr.astype(arr.dtype.newbyteorder(">")) if big else arr
        return SimpleNamespace(height=arr.shape[0], width=arr.shape[1], encoding=encoding, is_bigendian=int(big),
                               step=data.nbytes // arr.shape[0], data=np.frombuffer(data.tobytes(), np.uint8))

    np.testing.assert_array_equal(decode_image(msg(gray, "mono8"), "sensor_msgs/msg/Image"), gray)
    np.testing.assert_array_equal(decode_image(msg(bgr, "bgr8"), "sensor_msgs/msg/Image"), bgr)
    np.testing.assert_array_equal(decode_image(msg(bgr[..., ::-1].copy(), "rgb8"), "sensor_msgs/msg/Image"), bgr)
    np.testing.assert_array_equal(decode_image(msg(g16, "mono16"), "sensor_msgs/msg/Image"), g16)
    np.testing.assert_array_equal(decode_image(msg(g16, "mono16", big=True), "sensor_msgs/msg/Image"), g16)
    mm = np.full((H, W), 1500, np.uint16)
    assert depth_metres(decode_image(msg(mm, "16UC1"), "sensor_msgs/msg/Image"), "16UC1")[0, 0] == np.float32(1.5)
    metres = np.full((H, W), 2.25, np.float32)
    metres[0, 0] = np.nan
    out = depth_metres(decode_image(msg(metres, "32FC1"), "sensor_msgs/msg/Image"), "32FC1")
    assert out[0, 0] == 0.0 and out[1, 1] == np.float32(2.25)
    png = np.frombuffer(cv2.imencode(".png", bgr)[1].tobytes(), np.uint8)
    comp = SimpleNamespace(format="bgr8; png compressed bgr8", data=png)
    np.testing.assert_array_equal(decode_image(comp, "sensor_msgs/msg/CompressedImage"), bgr)
    jpg = SimpleNamespace(format="jpeg", data=np.frombuffer(cv2.imencode(".jpg", gray)[1].tobytes(), np.uint8))
    assert decode_image(jpg, "sensor_msgs/msg/CompressedImage").shape == (H, W)
    with pytest.raises(InputError, match="unknown image encoding 'yuv422'"):
        decode_image(msg(gray, "yuv422"), "sensor_msgs/msg/Image")
    with pytest.raises(InputError, match="compressedDepth"):
        decode_image(SimpleNamespace(format="16UC1; compressedDepth", data=png), "sensor_msgs/msg/CompressedImage")
    short = msg(gray, "mono8")
    short.data = short.data[:-1]
    with pytest.raises(InputError, match="needs 3072 bytes"):
        decode_image(short, "sensor_msgs/msg/Image")


def test_choose_topics_lists_candidates():
    img = "sensor_msgs/msg/Image"
    topics = [TopicSummary(n, img, 10, 10.0) for n in ("/a/left/image", "/a/right/image", "/b/cam0/image",
                                                       "/b/cam1/image", "/c/rgb/image", "/c/depth/image")]
    with pytest.raises(InputError, match=r"2 usable image topic pairs \(stereo: left /a/left/image.*cam0"):
        choose_topics(topics)
    assert choose_topics(topics, left="/b/cam0/image").second == "/b/cam1/image"
    rgbd = choose_topics(topics, depth="/c/depth/image")
    assert (rgbd.kind, rgbd.first, rgbd.second) == ("rgbd", "/c/rgb/image", "/c/depth/image")
    assert choose_topics(topics[4:]).kind == "rgbd"
    with pytest.raises(InputError, match="--right-topic /nope: no such image topic"):
        choose_topics(topics, left="/a/left/image", right="/nope")


# --------------------------------------------------------------------------------------------
# bad bags: one line naming the file, exit 2

def _bad_no_image(path: Path) -> Path:
    with BagWriter(path) as bag:
        bag.pose("/gt", 1_000_000_000, np.eye(4))
    return path


def _bad_encoding(path: Path) -> Path:
    return write_small_stereo(path, encoding="yuv422")


def _truncated(path: Path) -> Path:
    write_small_stereo(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return path


def _truncated_ros2(path: Path) -> Path:
    write_small_stereo(path)
    db = next(path.glob("*.db3"))
    data = db.read_bytes()
    db.write_bytes(data[: len(data) // 3])
    return path


@pytest.mark.parametrize("make, extra, message", [
    (_truncated, [], "cannot read bag"),
    (_truncated_ros2, [], "cannot read bag"),
    (_bad_no_image, [], "no image topic"),
    (_bad_encoding, [], "unknown image encoding 'yuv422'"),
    (lambda p: write_small_stereo(p), ["--left-topic", "/nope"], "--left-topic /nope: no such image topic"),
    (lambda p: write_small_stereo(p), ["--ground-truth-topic", "/nope"], "--ground-truth-topic /nope"),
    (lambda p: write_small_stereo(p, right_offset_ns=50_000_000), [], "never pair within 5 ms"),
    (lambda p: write_small_stereo(p, zero_info=True), [], "zero projection matrix P"),
])
def test_bad_bags_exit_2_with_one_line(tmp_path, capsys, make, extra, message):
    path = make(tmp_path / ("bad" if make is _truncated_ros2 else "bad.bag"))
    code, out, err = _run_cli(["run", str(path), "--out", str(tmp_path / "out"), "--no-progress"] + extra, capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and message in lines[0], err
    assert not (tmp_path / "out").exists()


def test_bag_options_on_a_folder_are_refused(tmp_path):
    (tmp_path / "rgb.txt").write_text("")
    (tmp_path / "depth.txt").write_text("")
    with pytest.raises(InputError, match="left_topic apply to ROS bags only"):
        open_sequence(tmp_path, left_topic="/x")
    with pytest.raises(InputError, match="not a ROS bag"):
        open_sequence(tmp_path, format="bag")


def test_info_command(tmp_path, capsys):
    bag = write_small_stereo(tmp_path / "a.bag", gt="geometry_msgs/msg/PoseStamped")
    code, out, _ = _run_cli(["info", str(bag)], capsys)
    assert code == 0
    assert "/cam/left/image_rect" in out and "sensor_msgs/msg/Image" in out and "10.00 Hz" in out
    assert "gtvo run would use: stereo, 5 frames" in out and "pose topics  /gt" in out
    code, out, _ = _run_cli(["info", str(bag), "--json", "--ground-truth-topic", "/gt"], capsys)
    info = json.loads(out)
    assert info["usable"] and info["ground_truth"] and info["frames"] == 5
    assert {t["name"]: t["count"] for t in info["topics"]}["/cam/right/image_rect"] == 5
    two = write_small_stereo(tmp_path / "b.bag", right_offset_ns=50_000_000)
    code, out, _ = _run_cli(["info", str(two)], capsys)
    assert code == 0 and "gtvo run would fail:" in out and "never pair" in out
    code, _, err = _run_cli(["info", str(_truncated(tmp_path / "c.bag"))], capsys)
    assert code == 2 and "cannot read bag" in err
    code, _, err = _run_cli(["run", str(tmp_path / "missing.bag")], capsys)
    assert code == 2 and "missing.bag: bag not found" in err


@pytest.mark.realdata
def test_info_on_a_folder(shared_data, capsys):
    code, out, _ = _run_cli(["info", str(shared_data / "rgbd_dataset_freiburg3_teddy_first20")], capsys)
    assert code == 0 and ": tum" in out and "gtvo run would use: rgbd, 20 frames" in out
    assert "fx 535.4" in out and "ground truth yes" in out


# --------------------------------------------------------------------------------------------
# real data: the bag run is the folder run

def _kitti_folder(shared_data: Path, tmp: Path) -> tuple[Path, list[int]]:
    """KITTI_sequence_1 as symlinks plus a times.txt of nanosecond stamps (t_i = 0.1 s i as the
    bag stores it), so the folder and the bag have the same frame times."""
    src = shared_data / "kitti_stereo_sample" / "KITTI_sequence_1"
    root = tmp / "KITTI_sequence_1"
    root.mkdir()
    for name in ("image_l", "image_r", "calib.txt", "poses.txt"):
        (root / name).symlink_to(src / name)
    count = len(list((src / "image_l").iterdir()))
    ns = [i * 100_000_000 for i in range(count)]
    (root / "times.txt").write_text("".join(f"{(n // 10**9) + (n % 10**9) / 1e9!r}\n" for n in ns))
    return root, ns


def _kitti_bag(root: Path, ns: list[int], path: Path, compressed: bool, mcap: bool = False) -> Path:
    from gtvo.datasets.kitti import read_projections

    PL, PR = read_projections(root / "calib.txt")
    seq = open_sequence(root)
    lefts = sorted((root / "image_l").iterdir())[:FRAMES + 2]
    with BagWriter(path, mcap=mcap) as bag:
        for i, left in enumerate(lefts):
            images = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in (left, root / "image_r" / left.name)]
            if i == 0:
                for side, P in (("left", PL), ("right", PR)):
                    bag.camera_info(f"/stereo/{side}/camera_info", ns[i], images[0].shape[1], images[0].shape[0],
                                    P[:, :3], P)
            for side, image in zip(("left", "right"), images):
                if compressed:
                    bag.compressed(f"/stereo/{side}/image_rect/compressed", ns[i], image, "png")
                else:
                    bag.image(f"/stereo/{side}/image_rect", ns[i], image, "mono8")
            bag.pose("/ground_truth", ns[i], seq.gt_poses[i])
    return path


@pytest.fixture(scope="module")
def kitti(shared_data, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("kitti_bag")
    root, ns = _kitti_folder(shared_data, tmp)
    return root, _kitti_bag(root, ns, tmp / "kitti.bag", compressed=False), \
        _kitti_bag(root, ns, tmp / "kitti_ros2", compressed=True, mcap=True)


@pytest.mark.slow
@pytest.mark.realdata
def test_kitti_bag_run_is_the_folder_run(kitti, tmp_path, capsys):
    root, ros1, _ = kitti
    common = ["--max-frames", str(FRAMES), "--mode", "track", "--no-progress"]
    assert cli_main(["run", str(root), "--out", str(tmp_path / "folder")] + common) == 0
    assert cli_main(["run", str(ros1), "--out", str(tmp_path / "bag"), "--ground-truth-topic", "/ground_truth",
                     "--left-topic", "/stereo/left/image_rect"] + common) == 0
    assert "unpaired_messages" in capsys.readouterr().out
    a, b = (json.loads((tmp_path / d / "report.json").read_text()) for d in ("folder", "bag"))
    assert a["frames"] == b["frames"] == FRAMES and a["ate_rmse_m"] is not None
    assert (tmp_path / "folder" / "trajectory.tum").read_bytes() == (tmp_path / "bag" / "trajectory.tum").read_bytes()
    assert b["ate_rmse_m"] == pytest.approx(a["ate_rmse_m"], rel=1e-9, abs=1e-12)
    assert b["unpaired_messages"] == {"/stereo/left/image_rect": 0, "/stereo/right/image_rect": 0}


@pytest.mark.slow
@pytest.mark.realdata
def test_kitti_ros2_compressed_bag_is_the_folder(kitti):
    from gtvo.pipeline import process_sequence
    import gtvo

    root, _, ros2 = kitti
    folder, bag = open_sequence(root, max_frames=FRAMES), open_sequence(ros2, max_frames=FRAMES)
    assert bag.camera == folder.camera
    np.testing.assert_array_equal(bag.timestamps, folder.timestamps)
    config = gtvo.OdometryConfig(mode="track")
    _, ta, _ = process_sequence(folder, config)
    _, tb, _ = process_sequence(bag, config)
    np.testing.assert_array_equal(tb.poses, ta.poses)


@pytest.mark.slow
@pytest.mark.realdata
@pytest.mark.parametrize("name", ["tum.bag", "tum_ros2"])
def test_tum_rgbd_bag_is_the_folder(shared_data, tmp_path, name):
    from gtvo.pipeline import process_sequence
    import gtvo

    root = shared_data / "rgbd_dataset_freiburg3_teddy_first20"
    folder = open_sequence(root, max_frames=FRAMES)
    rgb = [line.split() for line in (root / "rgb.txt").read_text().splitlines() if line and line[0] != "#"]
    depth = [line.split() for line in (root / "depth.txt").read_text().splitlines() if line and line[0] != "#"]
    gt = [line.split() for line in (root / "groundtruth.txt").read_text().splitlines() if line and line[0] != "#"]
    fx, fy, cx, cy = 535.4, 539.2, 320.1, 247.6
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    start, stop = stamp_from_text(rgb[0][0]) - 10**9, stamp_from_text(rgb[-1][0]) + 10**9
    with BagWriter(tmp_path / name) as bag:
        bag.camera_info("/camera/rgb/camera_info", stamp_from_text(rgb[0][0]), 640, 480, K, _P(K))
        for t, file in rgb:
            bgr = cv2.imread(str(root / file), cv2.IMREAD_UNCHANGED)
            bag.image("/camera/rgb/image_color", stamp_from_text(t), bgr[..., ::-1], "rgb8")
        for t, file in depth:
            d = cv2.imread(str(root / file), cv2.IMREAD_UNCHANGED).astype(np.float32) / np.float32(5000.0)
            bag.image("/camera/depth/image", stamp_from_text(t), d, "32FC1")
        for row in gt:
            ns = stamp_from_text(row[0])
            if start <= ns <= stop:
                T = np.eye(4)
                from scipy.spatial.transform import Rotation
                T[:3, :3] = Rotation.from_quat([float(v) for v in row[4:8]]).as_matrix()
                T[:3, 3] = [float(v) for v in row[1:4]]
                bag.pose("/mocap", ns, T)
    seq = open_sequence(tmp_path / name, max_frames=FRAMES, ground_truth_topic="/mocap")
    assert seq.kind == "rgbd" and seq.camera == folder.camera
    np.testing.assert_array_equal(seq.timestamps, folder.timestamps)
    np.testing.assert_allclose(seq.gt_poses, folder.gt_poses, atol=1e-9)
    np.testing.assert_array_equal(seq.depth(3), folder.depth(3))
    config = gtvo.OdometryConfig(mode="track")
    _, ta, _ = process_sequence(folder, config)
    _, tb, _ = process_sequence(seq, config)
    np.testing.assert_array_equal(tb.poses, ta.poses)


def test_camera_info_checks_and_rectified_topic_names():
    from gtvo.datasets.bag_types import RECTIFIED_TOPIC
    from gtvo.datasets.bag_calib import camera_model_from_msg

    assert RECTIFIED_TOPIC.search("/cam/left/image_rect") and RECTIFIED_TOPIC.search("/rectified/left/image")
    assert not RECTIFIED_TOPIC.search("/direct/left/image_raw")

    def info(**changes):
        roi = SimpleNamespace(width=0, height=0)
        base = dict(width=W, height=H, distortion_model="plumb_bob", d=np.zeros(5), k=K_SMALL.reshape(-1),
                    r=np.eye(3).reshape(-1), p=_P(K_SMALL).reshape(-1), binning_x=0, binning_y=0, roi=roi)
        base.update(changes)
        return SimpleNamespace(**base)

    assert camera_model_from_msg(info(), "bag: /ci").is_undistorted
    assert not camera_model_from_msg(info(d=np.array([0.1, 0, 0, 0, 0])), "bag: /ci").is_undistorted
    with pytest.raises(InputError, match="bag: /ci: .*zero intrinsic matrix K"):
        camera_model_from_msg(info(k=np.zeros(9), d=np.array([0.1, 0, 0, 0, 0])), "bag: /ci")
    with pytest.raises(InputError, match="binning"):
        camera_model_from_msg(info(binning_x=2), "bag: /ci")
    with pytest.raises(InputError, match="region of interest"):
        camera_model_from_msg(info(roi=SimpleNamespace(width=10, height=10)), "bag: /ci")
    with pytest.raises(InputError, match="distortion model 'equidistant'"):
        camera_model_from_msg(info(distortion_model="equidistant", d=np.array([0.1, 0, 0, 0])), "bag: /ci")


def test_small_rgbd_bag_16uc1_millimetres_and_subsampling(tmp_path):
    from gtvo.core.image import to_float_gray

    path = tmp_path / "rgbd"
    bgr = [np.stack([_texture(3 * i + c) for c in range(3)], axis=-1) for i in range(4)]
    mm = [np.full((H, W), 1000 + 250 * i, np.uint16) for i in range(4)]
    with BagWriter(path) as bag:
        bag.camera_info("/camera/rgb/camera_info", 10**9, W, H, K_SMALL, _P(K_SMALL))
        for i in range(4):
            ns = 10**9 + i * 33_000_000
            bag.image("/camera/rgb/image_color", ns, bgr[i][..., ::-1], "rgb8")
            bag.image("/camera/depth/image", ns + 10_000_000, mm[i], "16UC1")  # 10 ms later: within 20 ms
    seq = open_sequence(path)
    assert seq.kind == "rgbd" and len(seq) == 4 and seq.topics.second == "/camera/depth/image"
    np.testing.assert_array_equal(seq.left(2), to_float_gray(bgr[2]))
    np.testing.assert_array_equal(seq.depth(2), np.full((H, W), np.float32(1.5)))
    half = seq.subsampled(2)
    assert type(half) is type(seq) and len(half) == 2 and half.unpaired == seq.unpaired
    np.testing.assert_array_equal(half.depth(1), seq.depth(2))
    with pytest.raises(InputError, match="never pair within 5 ms"):
        open_sequence(path, stamp_tolerance=0.005)


@pytest.mark.realdata
def test_euroc_raw_bag_with_camera_info_or_sensor_yaml_is_the_folder(shared_data, tmp_path):
    """Raw (distorted) EuRoC images in a bag: rectified with the CameraInfo's own K, D, R, P
    (here those stereoRectify gives) or with --calib cam0/sensor.yaml, they equal the folder's."""
    from gtvo.datasets.euroc import read_sensor_yaml

    root = shared_data / "euroc_v101_static_stereo"
    mav0 = root / "mav0"
    folder = open_sequence(root, max_frames=4)
    raw0, T_B0 = read_sensor_yaml(mav0 / "cam0" / "sensor.yaml")
    raw1, T_B1 = read_sensor_yaml(mav0 / "cam1" / "sensor.yaml")
    T = np.linalg.inv(T_B1) @ T_B0
    R0, R1, P0, P1, *_ = cv2.stereoRectify(raw0.K, raw0.distortion, raw1.K, raw1.distortion, raw0.size,
                                           T[:3, :3].copy(), T[:3, 3].reshape(3, 1).copy(),
                                           flags=cv2.CALIB_ZERO_DISPARITY, alpha=0, newImageSize=raw0.size)
    rows = [line.split(",") for line in (mav0 / "cam0" / "data.csv").read_text().splitlines()[1:5]]
    with BagWriter(tmp_path / "euroc.bag") as bag:
        for cam, raw, R, P in (("cam0", raw0, R0, P0), ("cam1", raw1, R1, P1)):
            bag.camera_info(f"/{cam}/camera_info", int(rows[0][0]), raw.width, raw.height, raw.K, P,
                            D=np.append(raw.distortion, 0.0), R=R)
        for ns, name in rows:
            for cam in ("cam0", "cam1"):
                image = cv2.imread(str(mav0 / cam / "data" / name.strip()), cv2.IMREAD_UNCHANGED)
                bag.image(f"/{cam}/image_raw", int(ns), image, "mono8")
    for options in ({}, {"calib": mav0 / "cam0" / "sensor.yaml"}):
        seq = open_sequence(tmp_path / "euroc.bag", **options)
        assert seq.camera.left == folder.camera.left
        assert seq.camera.baseline == pytest.approx(folder.camera.baseline, rel=1e-12)
        # the EuRoC reader computes ns * 1e-9 (ns rounded to a float first), the bag sec + nsec / 1e9:
        # at 1.4e9 s they may differ by one float step (2.4e-7 s)
        np.testing.assert_allclose(seq.timestamps, folder.timestamps, rtol=0, atol=2.5e-7)
        for i in (0, 3):
            np.testing.assert_array_equal(seq.left(i), folder.left(i))
            np.testing.assert_array_equal(seq.right(i), folder.right(i))


def test_stamp_tolerance_the_warning_advises_is_a_flag_of_run_and_info(tmp_path, capsys):
    """The unpaired-messages warning advises --stamp-tolerance: gtvo run and gtvo info accept it
    (before: "unrecognized arguments"); a bad value is one line naming the flag."""
    path = write_small_stereo(tmp_path / "far.bag", right_offset_ns=50_000_000)  # 50 ms apart: never within 5 ms
    code, out, err = _run_cli(["info", str(path)], capsys)
    assert code == 0 and "gtvo run would fail" in out and "never pair within 5 ms" in out, out
    code, out, err = _run_cli(["info", str(path), "--stamp-tolerance", "0.06"], capsys)
    assert code == 0 and "gtvo run would use: stereo, 3 frames" in out, out
    for bad in ("0", "-1", "nan", "inf"):
        code, out, err = _run_cli(["run", str(path), "--stamp-tolerance", bad, "--out", str(tmp_path / "o"),
                                   "--no-progress"], capsys)
        assert code == 2 and err.count("\n") == 1 and "--stamp-tolerance must be a positive number" in err, err
    assert not (tmp_path / "o").exists()
    text = " ".join(_help_text(capsys, "run").split())
    assert "--stamp-tolerance SECONDS" in text and "5 ms for a stereo pair" in text


def _help_text(capsys, command):
    from gtvo.cli import main

    with pytest.raises(SystemExit):
        main([command, "--help"])
    return capsys.readouterr().out
