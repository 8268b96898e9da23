"""Ground truth is checked where it is read (issue 20, item 7): every reader of poses refuses a
rotation that is not one (KITTI: max |R^T R - I| > 1e-3 or det <= 0) and a quaternion that is
not unit length (EuRoC csv, TUM), with ``file:line``, also through ``--ground-truth``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_datasets import T0_NS, _raises, make_euroc, make_kitti, make_tum

from gtvo.cli import main
from gtvo.datasets import open_sequence


def _kitti_rows(path: Path) -> list[list[float]]:
    return [[float(x) for x in line.split()] for line in path.read_text().splitlines() if line.strip()]


def _write_rows(path: Path, rows: list[list[float]]) -> None:
    path.write_text("\n".join(" ".join(repr(x) for x in r) for r in rows) + "\n")


def _stretched(rows: list[list[float]], k: int) -> list[list[float]]:
    rows = [list(r) for r in rows]
    rows[k][0] = 1.3  # R[0, 0] = 1.3
    return rows


def _mirrored(rows: list[list[float]], k: int) -> list[list[float]]:
    rows = [list(r) for r in rows]
    for c in (2, 6, 10):  # third column of R negated: orthonormal, det -1
        rows[k][c] = -rows[k][c]
    return rows


@pytest.mark.parametrize("damage, needle", [(_stretched, "max |R^T R - I| = 0.69"), (_mirrored, "det -1")])
def test_kitti_poses_with_a_non_rotation_are_refused(tmp_path: Path, damage, needle: str) -> None:
    root = make_kitti(tmp_path / "seq")
    poses = root / "poses.txt"
    rows = _kitti_rows(poses)
    assert open_sequence(root).has_ground_truth
    _write_rows(poses, damage(rows, 1))
    err = _raises("poses.txt:2: rotation block is not a rotation", open_sequence, root)
    assert needle in str(err)
    # the same file through --ground-truth, beside a good poses.txt
    _write_rows(poses, rows)
    other = tmp_path / "other_poses.txt"
    _write_rows(other, damage(rows, 2))
    _raises("other_poses.txt:3: rotation block is not a rotation", open_sequence, root, ground_truth=other)


def test_gtvo_run_refuses_a_non_rotation_ground_truth(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = make_kitti(tmp_path / "seq")
    bad = tmp_path / "gt.txt"
    _write_rows(bad, _stretched(_kitti_rows(root / "poses.txt"), 0))
    assert main(["run", str(root), "--ground-truth", str(bad), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"gtvo run: error: {bad}:1: rotation block is not a rotation") and "\n" not in err
    assert not (tmp_path / "out").exists()


def test_euroc_ground_truth_quaternion_must_be_unit(tmp_path: Path) -> None:
    root = make_euroc(tmp_path / "V0")
    csv = root / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    lines = csv.read_text().splitlines()
    fields = lines[3].split(",")
    fields[4] = repr(1.3 * float(fields[4]) + 0.5)  # q_w: the norm moves far from 1
    lines[3] = ",".join(fields)
    csv.write_text("\n".join(lines) + "\n")
    _raises("data.csv:4: quaternion is not unit length", open_sequence, root)
    # --ground-truth as a TUM file
    gt = tmp_path / "gt.txt"
    gt.write_text(f"{T0_NS * 1e-9:.9f} 0 0 0 0 0 0 1\n{T0_NS * 1e-9 + 0.1:.9f} 0 0 0 0 0 0.5 1\n")
    _raises("gt.txt:2: quaternion is not unit length (norm 1.11803)", open_sequence, root, ground_truth=gt)


def test_tum_ground_truth_quaternion_must_be_unit(tmp_path: Path) -> None:
    root = make_tum(tmp_path / "rgbd_dataset_freiburg1_x")
    gt = root / "groundtruth.txt"
    lines = gt.read_text().splitlines()
    f = lines[5].split()
    f[7] = repr(float(f[7]) * 2.0)  # qw doubled
    lines[5] = " ".join(f)
    gt.write_text("\n".join(lines) + "\n")
    camera = (50.0, 50.5, 31.5, 23.5)
    _raises("groundtruth.txt:6: quaternion is not unit length", open_sequence, root, camera=camera)
    good = make_tum(tmp_path / "rgbd_dataset_freiburg1_y")
    _raises("groundtruth.txt:6: quaternion is not unit length", open_sequence, good, camera=camera, ground_truth=gt)


def test_printed_quaternions_still_read(tmp_path: Path) -> None:
    """Files print 4-9 digits: a norm within 1e-3 of 1 is normalised, not refused."""
    root = make_tum(tmp_path / "rgbd_dataset_freiburg1_z")
    gt = root / "groundtruth.txt"
    lines = gt.read_text().splitlines()
    f = lines[5].split()
    f[4:8] = [f"{float(x) * 1.0009:.4f}" for x in f[4:8]]
    lines[5] = " ".join(f)
    gt.write_text("\n".join(lines) + "\n")
    seq = open_sequence(root, camera=(50.0, 50.5, 31.5, 23.5))
    R = seq.gt_poses[:, :3, :3]
    assert np.allclose(np.swapaxes(R, 1, 2) @ R, np.eye(3), atol=1e-12)
