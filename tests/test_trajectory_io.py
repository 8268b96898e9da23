"""Trajectory files: round trips, bad input naming file:line, evo reads what we write."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gtvo.errors import InputError
from gtvo.io.plots import choose_plane, plot_errors_over_time, plot_trajectory_top_view, project_to_plane
from gtvo.evaluation.trajectory import Trajectory
from gtvo.core.lie import make_poses
from gtvo.io.trajectory_files import (detect_format, read_euroc_csv, read_kitti, read_times, read_trajectory, read_tum,
                                write_kitti, write_trajectory, write_tum)


def sample_trajectory(n: int = 25, seed: int = 0) -> Trajectory:
    rng = np.random.default_rng(seed)
    R = Rotation.from_rotvec(np.cumsum(rng.normal(scale=0.3, size=(n, 3)), axis=0)).as_matrix()
    p = np.cumsum(rng.normal(size=(n, 3)), axis=0) * np.pi  # digits that need full precision
    t = 1403715524.907143 + np.cumsum(rng.uniform(0.01, 0.1, n)) / 3.0
    return Trajectory(t, make_poses(R, p), name="sample")


def write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


# ---- round trips ----------------------------------------------------------------------------------

def test_tum_roundtrip_is_exact(tmp_path):
    traj = sample_trajectory()
    path = write_tum(tmp_path / "a.txt", traj)
    back = read_tum(path)
    np.testing.assert_array_equal(back.timestamps, traj.timestamps)  # repr: bit-exact
    np.testing.assert_array_equal(back.positions, traj.positions)
    np.testing.assert_allclose(back.rotations, traj.rotations, atol=1e-15)  # via a quaternion
    assert back.name == str(path)
    assert not list(tmp_path.glob(".a.txt*"))  # no temporary left behind


def test_kitti_roundtrip_with_and_without_times(tmp_path):
    traj = sample_trajectory()
    write_kitti(tmp_path / "k.txt", traj, times_path=tmp_path / "times.txt")
    back = read_kitti(tmp_path / "k.txt", tmp_path / "times.txt")
    np.testing.assert_array_equal(back.poses, traj.poses)
    np.testing.assert_array_equal(back.timestamps, traj.timestamps)
    no_times = read_kitti(tmp_path / "k.txt")
    np.testing.assert_array_equal(no_times.timestamps, np.arange(len(traj)))
    np.testing.assert_array_equal(read_times(tmp_path / "times.txt"), traj.timestamps)


def test_euroc_csv_reader_hand_case(tmp_path):
    # 90 deg about z: q_wxyz = (cos 45, 0, 0, sin 45); extra columns are ignored.
    c = float(np.sqrt(0.5))
    path = write(tmp_path, "data.csv", "#timestamp, p_x, p_y, p_z, q_w, q_x, q_y, q_z, v_x\n"
                 f"1403715524907143168,1.0,2.0,3.0,{c!r},0,0,{c!r},9\n"
                 f"1403715524912143104,1.5,2.0,3.0,1,0,0,0,9\n")
    traj = read_euroc_csv(path)
    np.testing.assert_allclose(traj.timestamps, [1403715524.907143168, 1403715524.912143104], rtol=0, atol=1e-6)
    np.testing.assert_allclose(traj.rotations[0], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    np.testing.assert_array_equal(traj.positions[1], [1.5, 2.0, 3.0])
    assert detect_format(path) == "euroc"


def test_tum_comments_and_blank_lines(tmp_path):
    path = write(tmp_path, "c.txt", "# header\n\n1.0 0 0 0 0 0 0 1  # inline comment\n  \n2.0 1 0 0 0 0 0 -1\n")
    traj = read_tum(path)
    assert len(traj) == 2
    np.testing.assert_allclose(traj.rotations, np.tile(np.eye(3), (2, 1, 1)))  # -q is the same rotation


def test_read_trajectory_detects_and_dispatches(tmp_path):
    traj = sample_trajectory(5)
    write_trajectory(tmp_path / "t.txt", traj, "tum")
    write_trajectory(tmp_path / "k.txt", traj, "kitti")
    assert detect_format(tmp_path / "t.txt") == "tum"
    assert detect_format(tmp_path / "k.txt") == "kitti"
    np.testing.assert_array_equal(read_trajectory(tmp_path / "k.txt").poses, traj.poses)
    np.testing.assert_array_equal(read_trajectory(tmp_path / "t.txt", "tum").timestamps, traj.timestamps)
    with pytest.raises(InputError, match="format"):
        write_trajectory(tmp_path / "x.txt", traj, "euroc")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="values per line"):
        detect_format(write(tmp_path, "odd.txt", "1 2 3\n"))


# ---- evo reads what we write ------------------------------------------------------------------------

def test_evo_reads_our_files(tmp_path):
    file_interface = pytest.importorskip("evo.tools.file_interface")
    traj = sample_trajectory()
    write_tum(tmp_path / "a.txt", traj)
    write_kitti(tmp_path / "k.txt", traj)
    e_tum = file_interface.read_tum_trajectory_file(str(tmp_path / "a.txt"))
    np.testing.assert_array_equal(e_tum.timestamps, traj.timestamps)
    np.testing.assert_allclose(np.array(e_tum.poses_se3), traj.poses, atol=1e-14)
    e_kitti = file_interface.read_kitti_poses_file(str(tmp_path / "k.txt"))
    np.testing.assert_array_equal(np.array(e_kitti.poses_se3), traj.poses)


@pytest.mark.slow
@pytest.mark.realdata
def test_readers_agree_with_evo_on_real_files(shared_data):
    file_interface = pytest.importorskip("evo.tools.file_interface")
    d = shared_data / "trajectory_eval_evo"
    for name in ("freiburg1_xyz-rgbdslam.txt", "V101_gt.txt", "fr2_desk_ORB_kf_mono.txt"):
        ours, theirs = read_tum(d / name), file_interface.read_tum_trajectory_file(str(d / name))
        np.testing.assert_array_equal(ours.timestamps, theirs.timestamps)
        np.testing.assert_allclose(ours.poses, np.array(theirs.poses_se3), atol=1e-12)
    ours, theirs = read_euroc_csv(d / "V102_groundtruth.csv"), file_interface.read_euroc_csv_trajectory(
        str(d / "V102_groundtruth.csv"))
    np.testing.assert_array_equal(ours.timestamps, theirs.timestamps)
    np.testing.assert_allclose(ours.poses, np.array(theirs.poses_se3), atol=1e-12)
    ours, theirs = read_kitti(d / "KITTI_00_gt.txt"), file_interface.read_kitti_poses_file(str(d / "KITTI_00_gt.txt"))
    np.testing.assert_array_equal(ours.poses, np.array(theirs.poses_se3))


# ---- bad input ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("reader, text, message, line", [
    (read_tum, "1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n", "needs 8 values, found 7", 2),
    (read_tum, "# h\n1 0 0 0 0 0 0 1\n2 0 0 x 0 0 0 1\n", "not a number: 'x'", 3),
    (read_tum, "1 0 0 0 0 0 0 1\n2 0 nan 0 0 0 0 1\n", "NaN", 2),
    (read_tum, "1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 0\n", "not unit length", 2),
    (read_tum, "1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0.5 1\n", "not unit length", 2),
    (read_tum, "1 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n", "backwards", 2),
    (read_kitti, "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n", "needs 12 values", 2),
    (read_kitti, "1 0 0 0 0 1 0 0 0 0 1 0\n2 0 0 0 0 1 0 0 0 0 1 0\n", "not a rotation", 2),
    (read_kitti, "1 0 0 0 0 1 0 0 0 0 -1 0\n", "not a rotation", 1),
    (read_kitti, "1 0 0 0 0 1 0 0 0 0 1 inf\n", "NaN or infinite", 1),
    (read_euroc_csv, "#t,x\n100,0,0,0,1,0,0\n", "at least 8 values", 2),
    (read_euroc_csv, "100,0,0,0,1,0,0,0\n50,0,0,0,1,0,0,0\n", "backwards", 2),
    (read_euroc_csv, "100,0,0,0,2,0,0,0\n", "not unit length", 1),
])
def test_malformed_lines_name_file_and_line(tmp_path, reader, text, message, line):
    path = write(tmp_path, "bad.txt", text)
    with pytest.raises(InputError, match=message) as info:
        reader(path)
    assert str(info.value).startswith(f"{path}:{line}: ")
    assert "\n" not in str(info.value)
    assert info.value.line == line


def test_missing_empty_and_binary_files(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_tum(tmp_path / "nope.txt")
    with pytest.raises(InputError, match="no poses"):
        read_tum(write(tmp_path, "empty.txt", "# only a comment\n\n"))
    (tmp_path / "bin.txt").write_bytes(b"\xff\xfe\x00\x81garbage")
    with pytest.raises(InputError, match="not a text file"):
        read_kitti(tmp_path / "bin.txt")


def test_kitti_times_count_mismatch(tmp_path):
    write_kitti(tmp_path / "k.txt", sample_trajectory(4))
    times = write(tmp_path, "times.txt", "0\n0.1\n0.2\n")
    with pytest.raises(InputError, match="3 times but") as info:
        read_kitti(tmp_path / "k.txt", times)
    assert str(times) in str(info.value)


# ---- plots ---------------------------------------------------------------------------------------------

def test_plane_choice():
    rng = np.random.default_rng(1)
    xz = np.column_stack([rng.normal(size=200) * 50, rng.normal(size=200) * 0.5, rng.normal(size=200) * 30])
    assert choose_plane(xz) == "xz"  # camera-frame world: y (down) barely moves
    assert choose_plane(xz[:, [0, 2, 1]]) == "xy"  # z-up world
    tilted = xz @ Rotation.from_rotvec([np.radians(50), 0, 0]).as_matrix().T
    assert choose_plane(tilted) == "pca"
    assert choose_plane(xz, "yz") == "yz"
    uv, xl, yl = project_to_plane(xz, "xz")
    np.testing.assert_array_equal(uv, xz[:, [0, 2]])
    assert (xl, yl) == ("x [m]", "z [m]")
    uv, _, _ = project_to_plane(tilted, "pca")
    # The principal-axis plane keeps almost all of the spread (only the 0.5 m one is dropped),
    # while the coordinate plane x-y of the tilted cloud would lose a lot of it.
    total = np.sum((tilted - tilted.mean(0)) ** 2)
    assert np.sum(uv ** 2) > 0.999 * total
    assert np.sum((tilted[:, :2] - tilted[:, :2].mean(0)) ** 2) < 0.9 * total
    with pytest.raises(InputError):
        choose_plane(xz, "ab")  # type: ignore[arg-type]


def test_plots_write_png(tmp_path):
    traj = sample_trajectory(40)
    out = plot_trajectory_top_view(traj.transform(np.eye(4), 1.01), traj, tmp_path / "sub" / "top.png", "t")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out = plot_trajectory_top_view(traj, None, tmp_path / "alone.png", plane="pca")
    assert out.stat().st_size > 1000
    out = plot_errors_over_time(traj.timestamps, np.linspace(0, 1, 40), tmp_path / "err.png", "ATE")
    assert out.read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in tmp_path.rglob("*") if p.is_file()) == ["alone.png", "err.png", "top.png"]
    with pytest.raises(InputError):
        plot_errors_over_time([0.0, 1.0], [1.0], tmp_path / "bad.png")


def test_errors_png_says_which_alignment_its_errors_are_after(tmp_path, monkeypatch):
    """errors.png of a run: the position error after SE(3) alignment (the ATE's), said in the
    title and on the axis."""
    import gtvo.io.outputs as outputs
    from gtvo.datasets.synthetic import make_synthetic_sequence
    from gtvo.evaluation.accuracy import evaluate, ground_truth

    seq = make_synthetic_sequence(n_frames=6)
    poses = seq.gt_poses.copy()
    poses[:, 0, 3] += 0.01 * np.arange(len(poses))
    drawn = {}
    real = outputs.plot_errors_over_time

    def capture(times, errors, path, title="", ylabel="error [m]"):
        drawn.update(title=title, ylabel=ylabel)
        return real(times, errors, path, title=title, ylabel=ylabel)

    monkeypatch.setattr(outputs, "plot_errors_over_time", capture)
    est = Trajectory(seq.timestamps.copy(), poses)
    metrics = evaluate(*ground_truth(seq, est))  # the report's figures, as gtvo.report.run_report adds them
    report = outputs.write_run_outputs(tmp_path / "out", est, seq, {"frames": 6, **metrics})
    assert report["ate_rmse_m"] is not None and (tmp_path / "out" / "errors.png").is_file()
    assert "after SE(3) alignment to the ground truth" in drawn["title"]
    assert drawn["ylabel"] == "position error after alignment [m]"
    outputs.write_run_outputs(tmp_path / "out2", est, seq, {"frames": 6, "ate_rmse_m": None})
    assert "after aligning the first poses" in drawn["title"]
