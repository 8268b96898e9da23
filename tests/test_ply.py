"""gtvo.io.ply: points.ply written with numpy (no open3d): its bytes, open3d reading it, and a
write the system refuses (a file-size limit standing in for a full disk) as one OSError with
nothing printed, no partial file and the earlier file intact."""

from __future__ import annotations

import errno
import json
import resource
import subprocess
import sys

import numpy as np
import pytest

from gtvo.io.ply import VERTEX, grey_levels, ply_header, read_ply_points, write_ply_points


def _points(n: int = 500, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.normal(0.0, 20.0, (n, 3)), rng.uniform(-5.0, 260.0, n)


def test_binary_ply_bytes_and_round_trip(tmp_path):
    pts, intensity = _points()
    path = write_ply_points(tmp_path / "points.ply", pts, intensity)
    data = path.read_bytes()
    header = ply_header(len(pts))
    assert data.startswith(b"ply\nformat binary_little_endian 1.0\n") and b"element vertex 500\n" in header
    assert b"property double x\n" in header and b"property uchar red\n" in header and header.endswith(b"end_header\n")
    assert len(data) == len(header) + 500 * VERTEX.itemsize == len(header) + 500 * 27
    back, grey = read_ply_points(path)
    np.testing.assert_array_equal(back, pts)
    np.testing.assert_array_equal(grey, grey_levels(intensity))
    assert grey.min() == 0 and grey.max() == 255  # clipped
    # as open3d turned colours in [0, 1] into bytes: truncated
    np.testing.assert_array_equal(grey_levels([0.0, 1.0, 127.9, 254.99, 255.0]), [0, 1, 127, 254, 255])
    assert [p.name for p in tmp_path.iterdir()] == ["points.ply"]


def test_open3d_reads_it(tmp_path, open3d):
    pts, intensity = _points()
    path = write_ply_points(tmp_path / "points.ply", pts, intensity)
    cloud = open3d.io.read_point_cloud(str(path))
    np.testing.assert_array_equal(np.asarray(cloud.points), pts)
    np.testing.assert_allclose(np.asarray(cloud.colors)[:, 0] * 255.0, grey_levels(intensity), atol=1e-9)


def test_a_refused_write_is_one_oserror_without_a_word(tmp_path, capfd):
    pts, intensity = _points(5000)
    path = tmp_path / "points.ply"
    earlier = write_ply_points(path, pts[:10], intensity[:10]).read_bytes()
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, hard))  # (Python ignores SIGXFSZ: the write fails)
    try:
        with pytest.raises(OSError) as info:
            write_ply_points(path, pts, intensity)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    assert info.value.errno == errno.EFBIG
    assert capfd.readouterr() == ("", "")
    assert path.read_bytes() == earlier and [p.name for p in tmp_path.iterdir()] == ["points.ply"]


def test_gtvo_run_on_a_full_disk_is_one_line_and_keeps_the_earlier_outputs(tmp_path):
    """`gtvo run` whose writes the system refuses (a file-size limit): exit 2, one line naming
    the file, and the earlier run's set as it was."""
    from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti

    seq = write_sequence_kitti(make_synthetic_sequence(n_frames=5, width=160, height=120, seed=2), tmp_path / "seq")
    out = tmp_path / "out"
    command = [sys.executable, "-m", "gtvo", "run", str(seq), "--out", str(out), "--no-progress", "--mode", "track"]
    r = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    earlier = {p.name: p.read_bytes() for p in out.iterdir()}
    limit = len(earlier["points.ply"]) - 1  # points.ply (at least) no longer fits

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))

    r = subprocess.run(command, capture_output=True, text=True, timeout=300, preexec_fn=small_files)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gtvo run: error: ") and "File too large" in lines[0], r.stderr
    named = lines[0].split("gtvo run: error: ", 1)[1].split(": File too large")[0]
    assert named.startswith(f"{out}/") and named.rsplit("/", 1)[1] in earlier and "RPly" not in r.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == earlier
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "seq"]  # no staging folder left
    assert json.loads(earlier["report.json"])["map_points_written"] > 0
