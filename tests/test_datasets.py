"""Dataset readers (gtvo.datasets): small made-up folders in tmp_path, bad input, and the real data."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.cli import build_parser
from gtvo.datasets import FORMATS, READERS, detect_format, open_sequence, validate
from gtvo.datasets.readers import reader_named
from gtvo.datasets._common import associate_unique, interpolate_poses
from gtvo.errors import InputError

RNG = np.random.default_rng(7)
W, H = 64, 48


def _texture(h: int = H, w: int = W, channels: int = 0) -> np.ndarray:
    shape = (h, w) if channels == 0 else (h, w, channels)
    return RNG.integers(0, 256, size=shape, dtype=np.uint8)


def _raises(match: str, func, *args, **kwargs) -> InputError:
    """Call and expect a one-line InputError whose message contains ``match``."""
    with pytest.raises(InputError) as info:
        func(*args, **kwargs)
    message = str(info.value)
    assert "\n" not in message
    assert match in message, message
    return info.value


def _pose(rotvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


# ---------------------------------------------------------------------------------------------
# made-up folders

P0 = [50.0, 0, 31.5, 0, 0, 50.0, 23.5, 0, 0, 0, 1, 0]
P1 = [50.0, 0, 31.5, -50.0 * 0.25, 0, 50.0, 23.5, 0, 0, 0, 1, 0]


def make_kitti(root: Path, n: int = 3, labelled: bool = False, names=("image_0", "image_1"),
               poses: bool = True, times: bool = False) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    fmt = lambda v: " ".join(f"{x:.12e}" for x in v)  # noqa: E731
    if labelled:
        text = f"P0: {fmt(P0)}\nP1: {fmt(P1)}\nP2: {fmt(P0)}\nP3: {fmt(P1)}\nTr: {fmt(P0)}\n"
    else:
        text = f"{fmt(P0)}\n{fmt(P1)}\n"
    (root / "calib.txt").write_text(text)
    for d in names:
        (root / d).mkdir()
        for i in range(n):
            cv2.imwrite(str(root / d / f"{i:06d}.png"), _texture())
    if poses:
        rows = [_pose([0, 0.01 * i, 0], [0, 0, 1.0 * i])[:3].reshape(-1) for i in range(n)]
        (root / "poses.txt").write_text("\n".join(fmt(r) for r in rows))
    if times:
        (root / "times.txt").write_text("\n".join(f"{0.05 * i:.6e}" for i in range(n)) + "\n")
    return root


def _sensor_yaml(T_BS: np.ndarray, intrinsics=(50.0, 50.0, 31.5, 23.5), distortion=(-0.1, 0.01, 0.0, 0.0),
                 resolution=(W, H)) -> str:
    data = ", ".join(repr(float(x)) for x in T_BS.reshape(-1))
    return ("%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n"
            f"  data: [{data}]\nrate_hz: 20\nresolution: [{resolution[0]}, {resolution[1]}]\n"
            f"camera_model: pinhole\nintrinsics: [{', '.join(map(str, intrinsics))}]\n"
            "distortion_model: radial-tangential\n"
            f"distortion_coefficients: [{', '.join(map(str, distortion))}]\n")


T_BS0 = _pose([0.02, -0.01, 1.5], [0.01, -0.06, 0.01])
T_BS1 = T_BS0 @ _pose([0.003, 0.01, -0.004], [0.1, 0.001, -0.002])  # cam1 at +0.1 m along cam0's x
T0_NS = 1_400_000_000_000_000_000
DT_NS = 50_000_000


def body_pose(t: float) -> np.ndarray:
    """A smooth made-up body trajectory T_W_B(t), t in seconds since the first image."""
    return _pose([0.1 * t, 0.2 * t, -0.05 * t], [1.0 + 0.5 * t, -0.3 * t, 0.2 * t * t])


def make_euroc(root: Path, n: int = 4, gt: str = "inside") -> Path:
    mav0 = root / "mav0"
    for cam, T in (("cam0", T_BS0), ("cam1", T_BS1)):
        (mav0 / cam / "data").mkdir(parents=True)
        (mav0 / cam / "sensor.yaml").write_text(_sensor_yaml(T))
        lines = ["#timestamp [ns],filename"]
        for i in range(n):
            ns = T0_NS + i * DT_NS
            cv2.imwrite(str(mav0 / cam / "data" / f"{ns}.png"), _texture())
            lines.append(f"{ns},{ns}.png")
        (mav0 / cam / "data.csv").write_text("\n".join(lines) + "\n")
    if gt != "none":
        # 200 Hz ground truth over the images (and a bit beyond), ASL columns
        rows = ["#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []"]
        for k in range(-2, n * 10 + 2):
            ns = T0_NS + k * 5_000_000
            T = body_pose((ns - T0_NS) * 1e-9)
            qx, qy, qz, qw = Rotation.from_matrix(T[:3, :3]).as_quat()
            values = (T[0, 3], T[1, 3], T[2, 3], qw, qx, qy, qz)
            rows.append(f"{ns}," + ",".join(repr(float(v)) for v in values) + ",0,0,0")
        target = (mav0 / "state_groundtruth_estimate0" / "data.csv") if gt == "inside" else root / "x_groundtruth.csv"
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text("\n".join(rows) + "\n")
    return root


#: intrinsics for the small made-up TUM folders (TUM's published ones are for 640x480)
TUM_CAMERA = (50.0, 50.5, 31.5, 23.5)


def make_tum(root: Path, n: int = 4, gt: bool = True, depth_offset: float = 0.005) -> Path:
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb_lines, depth_lines = ["# color images", "# timestamp filename"], ["# depth maps"]
    for i in range(n):
        t = 100.0 + i / 30.0
        cv2.imwrite(str(root / "rgb" / f"{t:.6f}.png"), _texture(channels=3))
        depth = np.full((H, W), 5000 * 2, dtype=np.uint16)
        depth[0, 0] = 0
        cv2.imwrite(str(root / "depth" / f"{t + depth_offset:.6f}.png"), depth)
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth_lines.append(f"{t + depth_offset:.6f} depth/{t + depth_offset:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    if gt:
        lines = ["# timestamp tx ty tz qx qy qz qw"]
        for k in range(0, int(n / 30.0 * 100) + 3):  # 100 Hz from t = 100.0
            t = 100.0 + k * 0.01
            T = body_pose(t - 100.0)
            q = Rotation.from_matrix(T[:3, :3]).as_quat()
            lines.append(f"{t:.4f} " + " ".join(repr(float(x)) for x in (*T[:3, 3], *q)))
        (root / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    return root


# ---------------------------------------------------------------------------------------------
# association helpers

def test_interpolate_poses_exact_on_a_constant_twist_and_nan_outside():
    twist_w, twist_v = np.array([0.2, -0.1, 0.3]), np.array([1.0, 0.5, -0.2])
    times = np.arange(0.0, 1.0001, 0.1)
    poses = np.array([_pose(twist_w * t, twist_v * t) for t in times])
    query = np.array([-0.5, 0.0, 0.25, 0.73, 1.0, 1.015, 1.5])
    out = interpolate_poses(times, poses, query, tolerance=0.02, max_gap=0.15)
    for k, t in enumerate(query):
        if 0.0 <= t <= 1.0:  # rotation about a fixed axis: slerp is exact; translation is linear
            np.testing.assert_allclose(out[k], _pose(twist_w * t, twist_v * t), atol=1e-12)
    np.testing.assert_allclose(out[5], poses[-1])  # 15 ms past the end: the nearest sample
    assert np.all(np.isnan(out[[0, 6]]))
    # a gap wider than max_gap is not interpolated: only the nearest within tolerance is used
    out = interpolate_poses(times[[0, 10]], poses[[0, 10]], np.array([0.01, 0.5]), tolerance=0.02, max_gap=0.15)
    np.testing.assert_allclose(out[0], poses[0])
    assert np.all(np.isnan(out[1]))


def test_associate_unique_uses_each_reference_once():
    reference = np.array([0.0, 1.0, 2.0])
    query = np.array([0.001, 0.009, 1.5, 2.015, 2.03])
    q, r = associate_unique(reference, query, tolerance=0.02)
    assert q.tolist() == [0, 3] and r.tolist() == [0, 2]


# ---------------------------------------------------------------------------------------------
# KITTI

@pytest.mark.parametrize("labelled", [False, True])
@pytest.mark.parametrize("names", [("image_0", "image_1"), ("image_l", "image_r")])
def test_kitti_made_up(tmp_path, labelled, names):
    root = make_kitti(tmp_path / "seq", labelled=labelled, names=names)
    assert detect_format(root) == "kitti"
    seq = open_sequence(root)
    assert seq.kind == "stereo" and len(seq) == 3
    assert seq.camera == StereoCamera(PinholeCamera(50.0, 50.0, 31.5, 23.5, W, H), 0.25)
    np.testing.assert_allclose(seq.timestamps, [0.0, 0.1, 0.2])
    np.testing.assert_allclose(seq.gt_poses[2], _pose([0, 0.02, 0], [0, 0, 2.0]), atol=1e-12)
    expected = cv2.imread(str(root / names[1] / "000001.png"), cv2.IMREAD_UNCHANGED).astype(np.float32)
    np.testing.assert_array_equal(seq.right(1), expected)
    assert seq.frame_names[0].endswith(f"{names[0]}/000000.png")
    validate(seq, progress=False)


def test_kitti_times_max_frames_and_no_poses(tmp_path):
    root = make_kitti(tmp_path / "seq", n=5, poses=False, times=True)
    seq = open_sequence(root, format="kitti", max_frames=2)
    assert len(seq) == 2 and seq.gt_poses is None
    np.testing.assert_allclose(seq.timestamps, [0.0, 0.05])


def test_kitti_release_layout_finds_its_poses_folder(tmp_path):
    """The KITTI odometry release keeps ground truth apart: dataset/poses/07.txt for
    dataset/sequences/07. A poses.txt inside the folder, or --ground-truth, still wins."""
    root = make_kitti(tmp_path / "dataset" / "sequences" / "07", labelled=True)
    (tmp_path / "dataset" / "poses").mkdir()
    (root / "poses.txt").rename(tmp_path / "dataset" / "poses" / "07.txt")
    seq = open_sequence(root)
    np.testing.assert_allclose(seq.gt_poses[2], _pose([0, 0.02, 0], [0, 0, 2.0]), atol=1e-12)
    (tmp_path / "dataset" / "poses" / "07.txt").rename(tmp_path / "dataset" / "poses" / "08.txt")
    assert open_sequence(root).gt_poses is None  # another sequence's poses are not taken
    other = make_kitti(tmp_path / "elsewhere" / "07", poses=False)
    assert open_sequence(other).gt_poses is None
    (tmp_path / "dataset" / "poses" / "08.txt").rename(tmp_path / "dataset" / "poses" / "09.txt")
    (tmp_path / "dataset" / "sequences" / "09").symlink_to(other)  # a linked sequence folder
    assert open_sequence(tmp_path / "dataset" / "sequences" / "09").gt_poses is not None
    (tmp_path / "dataset" / "poses" / "09.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    _raises("09.txt: 1 poses for 3 images: 09.txt needs one line per image", open_sequence,
            tmp_path / "dataset" / "sequences" / "09")


def test_camera_errors_name_their_source(tmp_path):
    root = make_kitti(tmp_path / "seq", poses=False)
    bad = list(P0)
    bad[2] = 400.0  # cx far off the 64x48 image
    fmt = lambda v: " ".join(f"{x:.12e}" for x in v)  # noqa: E731
    calib = root / "calib.txt"
    calib.write_text(f"{fmt(bad)}\n{fmt([*bad[:3], -12.5, *bad[4:]])}\n")
    _raises("calib.txt: camera principal point (cx, cy) = (400, 23.5) lies outside the 64x48 image (from P0)",
            open_sequence, root)
    tum = make_tum(tmp_path / "freiburg3_cam", gt=False)
    _raises("--camera (50, 50, 480, 640): camera principal point", open_sequence, tum, camera=(50, 50, 480, 640))


@pytest.mark.parametrize("labelled", [True, False])
def test_kitti_colour_pair_uses_p2_p3_and_carries_the_ground_truth_to_cam2(tmp_path, labelled):
    """Only image_2/image_3 (KITTI's colour download): K and the baseline come from P2 and P3, each
    camera sits at t_i = K^-1 P_i[:, 3] from cam0 (KITTI 00 has a few mm of y and z in them), and
    poses.txt, which is cam0's, is carried to cam2: projecting a world point with the returned
    pose and K gives what P2 gives for its cam0 coordinates."""
    K = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
    t2, t3 = np.array([0.06, -0.0003, 0.0038]), np.array([-0.47, 0.003, 0.0049])
    proj = {"P0": K @ np.c_[np.eye(3), np.zeros(3)], "P1": K @ np.c_[np.eye(3), [-0.54, 0, 0]],
            "P2": K @ np.c_[np.eye(3), t2], "P3": K @ np.c_[np.eye(3), t3]}
    root = make_kitti(tmp_path / "seq", names=("image_2", "image_3"))
    for d in ("image_2", "image_3"):
        for png in (root / d).iterdir():
            cv2.imwrite(str(png), _texture(channels=3))
    fmt = lambda P: " ".join(f"{x:.12e}" for x in P.reshape(-1))  # noqa: E731
    (root / "calib.txt").write_text("".join((f"{k}: " if labelled else "") + fmt(P) + "\n" for k, P in proj.items()))
    seq = open_sequence(root)
    assert seq.camera.left == PinholeCamera(50.0, 50.0, 31.5, 23.5, W, H)
    assert seq.camera.baseline == pytest.approx(0.53, abs=1e-9)
    assert seq.left(0).shape == (H, W)  # colour read as gray
    cam0_poses = np.stack([_pose([0, 0.01 * i, 0], [0, 0, 1.0 * i]) for i in range(3)])
    X_world = np.array([0.3, -0.2, 6.0, 1.0])
    for T_world_cam0, T_world_cam2 in zip(cam0_poses, seq.gt_poses):
        X_cam0 = np.linalg.solve(T_world_cam0, X_world)
        X_cam2 = np.linalg.solve(T_world_cam2, X_world)
        np.testing.assert_allclose(K @ X_cam2[:3], proj["P2"] @ X_cam0, rtol=1e-12)
    (root / "calib.txt").write_text(("P0: " if labelled else "") + fmt(proj["P0"]) + "\n"
                                    + ("P1: " if labelled else "") + fmt(proj["P1"]) + "\n")
    _raises("no P2 or P3 line" if labelled else "expected P2 and P3 lines", open_sequence, root)


def test_kitti_bad_calibration_lines(tmp_path):
    root = make_kitti(tmp_path / "seq")
    calib = root / "calib.txt"
    good = calib.read_text().splitlines()
    calib.write_text(good[0] + "\n" + " ".join(good[1].split()[:11]) + "\n")
    _raises("calib.txt:2: projection matrix needs 12 numbers", open_sequence, root)
    calib.write_text(good[0].replace("5.000000000000e+01", "abc", 1) + "\n" + good[1] + "\n")
    _raises("calib.txt:1: not a number: 'abc'", open_sequence, root)
    calib.write_text(good[0] + "\n" + good[1].replace("5.000000000000e+01", "nan", 1) + "\n")
    _raises("calib.txt:2: NaN or infinite value", open_sequence, root)
    calib.write_text("P0: " + good[0] + "\nP2: " + good[1] + "\n")
    _raises("calib.txt: no P1 line", open_sequence, root)
    calib.write_text(good[0] + "\n")
    _raises("expected P0 and P1 lines", open_sequence, root)
    calib.write_text(good[0] + "\n" + good[0] + "\n")
    _raises("must be positive", open_sequence, root)
    for blank in ("", "\n  \n", "# only a comment\n"):
        calib.write_text(blank)
        _raises("calib.txt: empty calibration file: no P0 or P1 line", open_sequence, root)


def test_kitti_missing_right_image_and_empty(tmp_path):
    root = make_kitti(tmp_path / "seq")
    (root / "image_1" / "000001.png").unlink()
    _raises("missing right image for left image", open_sequence, root)
    assert len(open_sequence(root, max_frames=1)) == 1  # the frames used are all there
    empty = make_kitti(tmp_path / "empty", n=0, poses=False)
    _raises("empty sequence", open_sequence, empty)


def test_kitti_corrupt_and_mismatched_images(tmp_path):
    root = make_kitti(tmp_path / "seq")
    left = root / "image_0" / "000001.png"
    left.write_bytes(left.read_bytes()[:60])  # truncated png
    seq = open_sequence(root)
    err = _raises("cannot read image", seq.left, 1)
    assert err.path == left
    _raises(str(left), validate, seq, progress=False)
    cv2.imwrite(str(left), _texture())
    cv2.imwrite(str(root / "image_1" / "000002.png"), _texture(H, W + 2))
    err = _raises("mismatched size", validate, open_sequence(root), progress=False)
    assert err.path == root / "image_1" / "000002.png"


def test_kitti_pose_and_time_count_mismatch(tmp_path):
    root = make_kitti(tmp_path / "seq", times=True)
    poses = root / "poses.txt"
    poses.write_text("\n".join(poses.read_text().splitlines()[:2]))
    _raises("2 poses for 3 images", open_sequence, root)
    make_kitti(tmp_path / "seq2").joinpath("times.txt").write_text("0\n0.1\n")
    _raises("2 timestamps for 3 images", open_sequence, tmp_path / "seq2")
    (tmp_path / "seq2" / "times.txt").write_text("0\n0.1\n0.1\n")
    err = _raises("times.txt:3: timestamps are not strictly increasing", open_sequence, tmp_path / "seq2")
    assert err.path == tmp_path / "seq2" / "times.txt"
    (tmp_path / "seq2" / "times.txt").write_text("0\n0.1 x\n0.2\n")
    _raises("times.txt:2: expected one timestamp per line", open_sequence, tmp_path / "seq2")


# ---------------------------------------------------------------------------------------------
# EuRoC

@pytest.mark.parametrize("gt", ["inside", "beside"])
def test_euroc_made_up_ground_truth_is_for_the_rectified_left_camera(tmp_path, gt):
    root = make_euroc(tmp_path / "V0", gt=gt)
    assert detect_format(root) == "euroc" and detect_format(root / "mav0") == "euroc"
    seq = open_sequence(root)
    assert seq.kind == "stereo" and len(seq) == 4
    assert seq.camera.baseline == pytest.approx(np.linalg.norm(T_BS1[:3, 3] - T_BS0[:3, 3]), rel=1e-9)
    np.testing.assert_allclose(np.diff(seq.timestamps), DT_NS * 1e-9, atol=5e-7)  # float64 s since 1970
    # expected: T_W_B(t) * T_BS0 * T_cam0_rect, with R_cam0_rect the rotation taking rectified-left
    # coordinates to cam0's: recompute the rectification with OpenCV directly
    from gtvo.datasets.euroc import read_sensor_yaml
    raw0, _ = read_sensor_yaml(root / "mav0" / "cam0" / "sensor.yaml")
    raw1, _ = read_sensor_yaml(root / "mav0" / "cam1" / "sensor.yaml")
    T10 = np.linalg.inv(T_BS1) @ T_BS0
    R_rect_cam0 = cv2.stereoRectify(raw0.K, raw0.distortion, raw1.K, raw1.distortion, (W, H), T10[:3, :3],
                                    T10[:3, 3:], flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)[0]
    for i in range(len(seq)):
        expected = body_pose(i * DT_NS * 1e-9) @ T_BS0
        expected[:3, :3] = expected[:3, :3] @ R_rect_cam0.T
        np.testing.assert_allclose(seq.gt_poses[i], expected, atol=2e-6)  # interpolation between 5 ms samples
    img = seq.left(0)
    assert img.shape == (H, W) and img.dtype == np.float32
    validate(seq, progress=False)


def test_euroc_no_ground_truth_and_explicit_tum_ground_truth(tmp_path):
    root = make_euroc(tmp_path / "V0", gt="none")
    assert open_sequence(root).gt_poses is None
    tum = tmp_path / "gt.txt"
    lines = []
    for i in range(4):
        T = body_pose(i * 0.05)
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        lines.append(f"{(T0_NS + i * DT_NS) * 1e-9:.9f} " + " ".join(repr(float(x)) for x in (*T[:3, 3], *q)))
    tum.write_text("\n".join(lines))
    seq = open_sequence(root, ground_truth=tum)
    assert seq.has_ground_truth
    np.testing.assert_allclose(seq.gt_poses[3][:3, 3], (body_pose(0.15) @ T_BS0)[:3, 3], atol=1e-6)


def test_euroc_bad_input(tmp_path):
    root = make_euroc(tmp_path / "V0")
    cam1_csv = root / "mav0" / "cam1" / "data.csv"
    good_csv = cam1_csv.read_text()
    cam1_csv.write_text("\n".join(good_csv.splitlines()[:-1]) + "\n")
    _raises("missing right image for left image", open_sequence, root)
    cam1_csv.write_text(good_csv)
    (root / "mav0" / "cam1" / "data" / f"{T0_NS + DT_NS}.png").unlink()
    _raises("missing right image", open_sequence, root)

    root = make_euroc(tmp_path / "V1")
    yaml0 = root / "mav0" / "cam0" / "sensor.yaml"
    yaml0.write_text(_sensor_yaml(T_BS0, intrinsics=(50.0, float("nan"), 31.5, 23.5)))
    _raises("sensor.yaml: intrinsics contains NaN", open_sequence, root)
    yaml0.write_text(_sensor_yaml(T_BS0, intrinsics=(50.0, 31.5, 23.5)))
    _raises("intrinsics needs 4 numbers", open_sequence, root)
    yaml0.write_text("T_BS: [1, 2\nfoo: {")
    _raises("sensor.yaml:", open_sequence, root)
    yaml0.write_text(_sensor_yaml(T_BS0, resolution=(W + 2, H)))
    _raises("mismatched size", open_sequence, root)
    yaml0.write_text(_sensor_yaml(T_BS0, resolution=(W + 0.5, H)))
    _raises("sensor.yaml: resolution must be two whole numbers", open_sequence, root)
    for cam in ("cam0", "cam1"):  # both agree, the images do not: no rectification tables of 1e12 x 1e12
        (root / "mav0" / cam / "sensor.yaml").write_text(_sensor_yaml(T_BS0 if cam == "cam0" else T_BS1,
                                                                     resolution=(10**12, 10**12)))
    _raises(f"cam0/sensor.yaml: resolution is 1000000000000x1000000000000 but the images are {W}x{H}",
            open_sequence, root)
    (root / "mav0" / "cam1" / "sensor.yaml").write_text(_sensor_yaml(T_BS1))
    sheared = T_BS0.copy()
    sheared[0, 1] += 0.01
    yaml0.write_text(_sensor_yaml(sheared))
    _raises("sensor.yaml: T_BS rotation block is not a rotation", open_sequence, root)
    mirrored = T_BS0 @ np.diag([1.0, 1.0, -1.0, 1.0])
    yaml0.write_text(_sensor_yaml(mirrored))
    _raises("T_BS rotation block is not a rotation", open_sequence, root)
    projective = T_BS0.copy()
    projective[3, 0] = 0.5
    yaml0.write_text(_sensor_yaml(projective))
    _raises("T_BS bottom row", open_sequence, root)

    root = make_euroc(tmp_path / "V2")
    csv0 = root / "mav0" / "cam0" / "data.csv"
    csv0.write_text("#timestamp [ns],filename\n123x,a.png\n")
    _raises("data.csv:2: not an integer nanosecond timestamp", open_sequence, root)
    csv0.write_text("#timestamp [ns],filename\n")
    _raises("empty sequence", open_sequence, root)


def test_euroc_ground_truth_outside_the_images_and_corrupt_image(tmp_path):
    root = make_euroc(tmp_path / "V0", gt="none")
    far = root / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    far.parent.mkdir()
    far.write_text(f"{T0_NS + 10**12},0,0,0,1,0,0,0\n{T0_NS + 10**12 + 5_000_000},0,0,0,1,0,0,0\n")
    _raises("does not overlap the images", open_sequence, root)
    far.write_text(f"{T0_NS},0,0,0,0,0,0,0\n")
    _raises("data.csv:1: quaternion is not unit length (norm 0)", open_sequence, root)
    far.unlink()
    wrong = root / "mav0" / "cam0" / "data" / f"{T0_NS + DT_NS}.png"
    cv2.imwrite(str(wrong), _texture(H - 1, W))
    err = _raises("mismatched size", open_sequence(root).left, 1)
    assert err.path == wrong
    img = root / "mav0" / "cam1" / "data" / f"{T0_NS}.png"
    img.write_bytes(img.read_bytes()[:-20])
    err = _raises("cannot read image", open_sequence(root).right, 0)
    assert err.path == img


# ---------------------------------------------------------------------------------------------
# TUM RGB-D

def test_tum_made_up(tmp_path):
    root = make_tum(tmp_path / "rgbd_dataset_freiburg1_made_up")
    assert detect_format(root) == "tum"
    # TUM's published freiburg1 intrinsics are for 640x480, these images are not
    _raises(f"the image is {W}x{H} but TUM's published intrinsics are for 640x480", open_sequence, root)
    seq = open_sequence(root, camera=TUM_CAMERA)
    assert seq.kind == "rgbd" and len(seq) == 4
    assert seq.camera == PinholeCamera(*TUM_CAMERA, W, H)
    depth = seq.depth(1)
    assert depth.dtype == np.float32 and depth[0, 0] == 0 and depth[5, 5] == pytest.approx(2.0)
    colour = cv2.imread(str(root / "rgb" / f"{100 + 1 / 30:.6f}.png"))
    np.testing.assert_allclose(seq.left(1), colour @ np.array([0.114, 0.587, 0.299]), atol=1e-3)
    for i, t in enumerate(seq.timestamps):  # rgb times 1/30 s apart, GT at 100 Hz: interpolated
        np.testing.assert_allclose(seq.gt_poses[i], body_pose(t - 100.0), atol=5e-5)
    seq = open_sequence(root, camera=(600, 601, 30, 20), max_frames=2)
    assert seq.camera == PinholeCamera(600, 601, 30, 20, W, H) and len(seq) == 2
    validate(seq, progress=False)


def test_tum_association_drops_unpaired_rgb(tmp_path):
    root = make_tum(tmp_path / "freiburg3_x", depth_offset=0.0)
    lines = (root / "depth.txt").read_text().splitlines()
    (root / "depth.txt").write_text("\n".join(lines[:2] + lines[3:]) + "\n")  # drop the 2nd depth image
    seq = open_sequence(root, camera=TUM_CAMERA)
    np.testing.assert_allclose(seq.timestamps, 100.0 + np.array([0, 2, 3]) / 30.0)


def test_tum_bad_input(tmp_path):
    root = make_tum(tmp_path / "some_rgbd_folder")
    _raises("pass --camera", open_sequence, root)
    _raises("four finite numbers", open_sequence, root, camera=(500, float("nan"), 1, 1))
    _raises("four finite numbers", open_sequence, root, camera=("fx", 500, 1, 1))
    _raises("four finite numbers", open_sequence, root, camera=500)
    assert len(open_sequence(root, camera=(500, 500, 32, 24))) == 4

    root = make_tum(tmp_path / "freiburg2_gt_elsewhere")
    gt = (root / "groundtruth.txt").read_text().splitlines()
    shifted = [" ".join([f"{float(l.split()[0]) + 50:.4f}"] + l.split()[1:]) for l in gt[1:]]
    (root / "groundtruth.txt").write_text("\n".join(shifted))
    _raises("does not overlap the images", open_sequence, root)
    (root / "groundtruth.txt").write_text("1.0 0 0 0 0 0 0\n")
    _raises("groundtruth.txt:1: expected at least 8 fields", open_sequence, root)

    root = make_tum(tmp_path / "freiburg3_sizes", gt=False)
    depth = sorted((root / "depth").iterdir())[2]
    cv2.imwrite(str(depth), np.zeros((H + 2, W), np.uint16))
    err = _raises("mismatched size", validate, open_sequence(root, camera=TUM_CAMERA), progress=False)
    assert err.path == depth
    cv2.imwrite(str(depth), np.zeros((H, W), np.uint8))
    _raises("16-bit", open_sequence(root, camera=TUM_CAMERA).depth, 2)

    root = make_tum(tmp_path / "freiburg3_far_depth", depth_offset=0.5, gt=False)
    _raises("no colour image has a depth image", open_sequence, root)
    root = make_tum(tmp_path / "freiburg3_empty", n=0, gt=False)
    _raises("empty sequence", open_sequence, root)
    (root / "rgb.txt").write_text("1.0 rgb/missing.png\n")
    (root / "depth.txt").write_text("1.0 depth/missing.png\n")
    _raises("not found", open_sequence, root)


# ---------------------------------------------------------------------------------------------
# auto-detection and generic bad input

def test_missing_and_unknown_folders(tmp_path):
    _raises("sequence folder not found", open_sequence, tmp_path / "nope")
    (tmp_path / "file.txt").write_text("x")
    _raises("file.txt: is a file, not a sequence folder or a ROS bag (a .bag file", detect_format,
            tmp_path / "file.txt")
    (tmp_path / "empty").mkdir()
    err = _raises("unknown dataset layout", open_sequence, tmp_path / "empty")
    assert "a ROS bag (a .bag file, or a ROS2 bag folder with metadata.yaml" in str(err)
    assert all(reader.layout in str(err) for reader in READERS)  # the message lists every reader's layout
    root = make_kitti(tmp_path / "k")
    _raises("max_frames must be >= 1", open_sequence, root, max_frames=0)
    _raises("unknown dataset format", open_sequence, root, format="las")
    _raises("camera apply to TUM folders only, this is kitti", open_sequence, root, camera=(1, 1, 1, 1))
    with pytest.raises(TypeError, match="unexpected keyword argument 'lefttopic'"):
        open_sequence(root, lefttopic="/l")  # a misspelt option is a programming error, not bad input
    _raises("KITTI sequence folder not found", open_sequence, tmp_path / "nope", format="kitti")


def test_the_registry_names_each_reader_once_and_detects_its_own_layout(tmp_path):
    assert FORMATS == tuple(r.name for r in READERS) and len(set(FORMATS)) == len(FORMATS)
    from tests.test_kitti_raw import make_raw  # noqa: PLC0415 - its maker of a raw drive

    made = {"kitti": make_kitti(tmp_path / "k"), "euroc": make_euroc(tmp_path / "e"), "tum": make_tum(tmp_path / "t"),
            "kitti_raw": make_raw(tmp_path / "r")}
    for name, root in made.items():
        assert detect_format(root) == name
        assert reader_named(name).looks_like(root)
        assert [r.name for r in READERS if r.looks_like(root)] == [name]  # no other reader claims it
        options = {"camera": (50.0, 50.0, 31.5, 23.5)} if name == "tum" else {}  # TUM's only option
        assert len(open_sequence(root, format=name, **options)) > 0


def _dataset_format_choices() -> dict[str, tuple[str, ...]]:
    """Every subcommand's ``--format`` choices (``posegraph``'s are graph-file formats, not datasets)."""
    parser = build_parser()
    commands = next(a for a in parser._actions if a.dest == "command").choices
    return {name: tuple(action.choices) for name, sub in commands.items() if name != "posegraph"
            for action in sub._actions if "--format" in action.option_strings}


def test_every_command_offers_the_same_formats_the_registry_has():
    choices = _dataset_format_choices()
    assert set(choices) == {"run", "info", "loops"}
    assert all(c == ("auto",) + FORMATS for c in choices.values()), choices
    args = build_parser().parse_args(["info", "LOG", "--format", "kitti_raw"])  # once refused by info
    assert args.format == "kitti_raw"


def test_batch_lists_accept_every_format(tmp_path):
    from gtvo.batching.spec import read_spec  # noqa: PLC0415

    log = str(make_kitti(tmp_path / "k"))
    entries = [{"path": log, "format": name, "name": name} for name in FORMATS]
    assert [s.format for s in read_spec(entries)] == list(FORMATS)
    _raises("unknown 'format' 'las' (known: auto, " + ", ".join(FORMATS), read_spec, [{"path": log, "format": "las"}])


# ---------------------------------------------------------------------------------------------
# real data

@pytest.mark.realdata
def test_real_kitti(shared_data):
    root = shared_data / "kitti_stereo_sample" / "KITTI_sequence_1"
    seq = open_sequence(root)
    assert len(seq) == 51 and seq.kind == "stereo"
    cam = seq.camera.left
    assert (cam.width, cam.height) == (1226, 370)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == pytest.approx((707.0912, 707.0912, 601.8873, 183.1104))
    assert seq.camera.baseline == pytest.approx(0.53715, abs=1e-5)
    assert seq.gt_poses.shape == (51, 4, 4)
    np.testing.assert_allclose(seq.gt_poses[0], np.eye(4), atol=1e-9)
    np.testing.assert_allclose(seq.gt_poses[1][:3, 3], [-1.401751e-02, -2.820321e-02, 1.198998e+00])
    assert np.linalg.norm(seq.gt_poses[-1][:3, 3]) == pytest.approx(59.9, abs=0.1)
    assert np.all(np.diff(seq.timestamps) > 0)
    assert seq.left(0).shape == (370, 1226) and seq.right(50).shape == (370, 1226)


@pytest.mark.realdata
def test_real_euroc(shared_data):
    from gtvo.datasets.euroc import read_sensor_yaml

    root = shared_data / "euroc_v101_static_stereo"
    raw0, T_BS_0 = read_sensor_yaml(root / "mav0" / "cam0" / "sensor.yaml")
    raw1, _ = read_sensor_yaml(root / "mav0" / "cam1" / "sensor.yaml")
    assert (raw0.K[0, 0], raw0.K[1, 1], raw0.K[0, 2], raw0.K[1, 2]) == (458.654, 457.296, 367.215, 248.375)
    assert (raw1.K[0, 0], raw1.K[1, 1], raw1.K[0, 2], raw1.K[1, 2]) == (457.587, 456.134, 379.999, 255.238)
    np.testing.assert_allclose(raw0.distortion, [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05])
    seq = open_sequence(root)
    assert len(seq) == 20 and seq.kind == "stereo"
    cam = seq.camera.left
    assert (cam.width, cam.height) == (752, 480)
    assert 400 < cam.fx < 470 and cam.fx == cam.fy  # rectified: shared K, square pixels
    assert seq.camera.baseline == pytest.approx(0.11008, abs=2e-4)
    assert np.all(np.diff(seq.timestamps) > 0)
    assert seq.timestamps[0] == pytest.approx(1403715273.262143, abs=1e-6)
    # GT: the first row of the openvins csv (the frames lie on its samples), carried to cam0 then rectified
    T_W_B = np.eye(4)
    T_W_B[:3, :3] = Rotation.from_quat([-0.824237, -0.106942, -0.551702, 0.069433]).as_matrix()
    T_W_B[:3, 3] = [0.878895, 2.1834, 0.948427]
    T_W_cam0 = T_W_B @ T_BS_0
    assert seq.gt_poses.shape == (20, 4, 4) and np.all(np.isfinite(seq.gt_poses))
    np.testing.assert_allclose(seq.gt_poses[0][:3, 3], T_W_cam0[:3, 3], atol=1e-9)
    # the rectified left camera is turned by a small rotation from raw cam0 (< 1 degree here)
    R_cam0_rect = T_W_cam0[:3, :3].T @ seq.gt_poses[0][:3, :3]
    angle = np.degrees(np.linalg.norm(Rotation.from_matrix(R_cam0_rect).as_rotvec()))
    assert 0.01 < angle < 1.0
    # static platform: every GT position within 2 mm of the first
    assert np.max(np.linalg.norm(seq.gt_poses[:, :3, 3] - seq.gt_poses[0, :3, 3], axis=1)) < 2e-3
    # the TUM copy of the same ground truth (0.1 ms rounded times) gives the same poses
    tum = open_sequence(root, ground_truth=root / "V1_01_easy_groundtruth_openvins_tum.txt")
    np.testing.assert_allclose(tum.gt_poses, seq.gt_poses, atol=1e-5)


@pytest.mark.realdata
def test_real_tum(shared_data):
    root = shared_data / "rgbd_dataset_freiburg3_teddy_first20"
    seq = open_sequence(root)
    assert len(seq) == 20 and seq.kind == "rgbd"
    assert seq.camera == PinholeCamera(535.4, 539.2, 320.1, 247.6, 640, 480)
    assert np.all(np.diff(seq.timestamps) > 0)
    assert seq.timestamps[0] == pytest.approx(1341841873.441849)
    depth = seq.depth(0)
    assert depth.shape == (480, 640) and np.any(depth == 0)
    assert 0.3 < np.median(depth[depth > 0]) < 5.0
    assert seq.left(0).shape == (480, 640)
    # first pose: translation linearly interpolated between the bracketing 100 Hz samples
    gt = np.loadtxt(root / "groundtruth.txt")
    t0 = seq.timestamps[0]
    expected_t = [np.interp(t0, gt[:, 0], gt[:, k]) for k in (1, 2, 3)]
    assert seq.gt_poses.shape == (20, 4, 4)
    np.testing.assert_allclose(seq.gt_poses[0][:3, 3], expected_t, atol=1e-9)
    near = int(np.argmin(np.abs(gt[:, 0] - t0)))
    R_near = Rotation.from_quat(gt[near, 4:8]).as_matrix()
    assert np.degrees(np.linalg.norm(Rotation.from_matrix(R_near.T @ seq.gt_poses[0][:3, :3]).as_rotvec())) < 1.0
    validate(seq, progress=False)


def _link_tree(src: Path, dst: Path, skip: set[str] = frozenset()) -> Path:
    """A copy of ``src`` in ``dst`` made of symlinks (files named in ``skip`` left out)."""
    for path in src.rglob("*"):
        rel = path.relative_to(src)
        if path.is_dir() or rel.as_posix() in skip:
            continue
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        (dst / rel).symlink_to(path)
    return dst


@pytest.mark.realdata
def test_real_data_damaged_copies(shared_data, tmp_path):
    kitti = shared_data / "kitti_stereo_sample" / "KITTI_sequence_1"
    root = _link_tree(kitti, tmp_path / "k1", skip={"poses.txt", "image_r/000017.png"})
    _raises("missing right image for left image", open_sequence, root)
    root = _link_tree(kitti, tmp_path / "k2", skip={"poses.txt"})
    (root / "poses.txt").write_text("\n".join((kitti / "poses.txt").read_text().splitlines()[:50]))
    _raises("50 poses for 51 images", open_sequence, root)
    (root / "image_l" / "000003.png").unlink()
    (root / "image_l" / "000003.png").write_bytes((kitti / "image_l" / "000003.png").read_bytes()[:5000])
    (root / "poses.txt").unlink()
    _raises("image_l/000003.png: cannot read image", validate, open_sequence(root), progress=False)

    euroc = shared_data / "euroc_v101_static_stereo"
    root = _link_tree(euroc, tmp_path / "e1")
    gt = tmp_path / "late.txt"
    rows = (euroc / "V1_01_easy_groundtruth_openvins_tum.txt").read_text().splitlines()[100:200]
    gt.write_text("\n".join(rows))
    _raises("does not overlap the images", open_sequence, root, ground_truth=gt)

    tum = shared_data / "rgbd_dataset_freiburg3_teddy_first20"
    root = _link_tree(tum, tmp_path / "teddy")  # the folder name no longer says freiburg3
    _raises("pass --camera", open_sequence, root)
    assert open_sequence(root, camera=(535.4, 539.2, 320.1, 247.6)).camera.fx == 535.4


def test_a_log_or_a_file_of_its_layout_that_is_a_link_loop_is_named(tmp_path):
    """A sequence folder that is a symbolic link loop, or a calib.txt / image folder that is one:
    the message names the loop (before: "not found", "unknown dataset layout")."""
    from gtvo.datasets import detect_format

    (tmp_path / "loop").symlink_to("loop")
    with pytest.raises(InputError, match=r"loop: sequence folder is a symbolic link loop$"):
        open_sequence(tmp_path / "loop")
    root = make_kitti(tmp_path / "seq")
    (root / "calib.txt").unlink()
    (root / "calib.txt").symlink_to("calib.txt")
    with pytest.raises(InputError, match=r"seq: calib.txt is a symbolic link loop: the layout cannot be recognised$"):
        detect_format(root)
    (root / "calib.txt").unlink()
    (root / "calib.txt").symlink_to(tmp_path / "gone")
    with pytest.raises(InputError, match="calib.txt is a broken symbolic link"):
        open_sequence(root)
