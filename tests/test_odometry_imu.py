"""The IMU in a run (gtvo.odometry.imu, VisualOdometry with an IMU): black frames carried by the IMU
(``imu_carried``), report.json's ``imu`` block, and the outputs in the gravity-aligned world."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from gtvo.cli import main as cli_main
from gtvo.core.lie import quaternions_to_rotations
from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti
from gtvo.datasets.synthetic_imu import SYNTHETIC_GRAVITY, ImuSimulation
from gtvo.odometry.imu import GravityAlignment

BLACK = range(24, 29)


def test_the_alignment_takes_gravity_down_the_z_axis():
    for g in (SYNTHETIC_GRAVITY, np.array([0.3, -9.7, 1.2]), np.array([0.0, 0.0, 9.8]), np.array([0, 0, -9.8])):
        R = GravityAlignment.of_gravity(g).R_aligned_world
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(R @ (g / np.linalg.norm(g)), [0, 0, -1], atol=1e-12)


@pytest.mark.slow
def test_black_frames_are_carried_by_the_imu_and_the_outputs_are_gravity_aligned(tmp_path, capsys):
    log = tmp_path / "log"
    seq = make_synthetic_sequence(40, width=240, height=180, motion="swerve", imu=ImuSimulation())
    write_sequence_kitti(seq, log)
    for i in BLACK:
        for side in ("image_0", "image_1"):
            cv2.imwrite(str(log / side / f"{i:06d}.png"), np.zeros((180, 240), np.uint8))
    runs = {}
    for name, extra in (("imu", []), ("vision", ["--no-imu"])):
        assert cli_main(["run", str(log), "--out", str(tmp_path / name), "--no-progress", *extra]) == 0
        runs[name] = json.loads((tmp_path / name / "report.json").read_text())
    capsys.readouterr()
    with_imu, vision = runs["imu"]["frame_outcomes"], runs["vision"]["frame_outcomes"]
    assert [f["index"] for f in with_imu["imu_carried"]] == list(BLACK) and with_imu["lost"] == []
    assert "placed by the IMU" in with_imu["imu_carried"][0]["reason"]
    assert [f["index"] for f in vision["lost"]] == list(BLACK) and vision["imu_carried"] == []
    imu = runs["imu"]["imu"]
    assert imu["initialised"] == "moving" and imu["gyro_bias_sigma"] is not None
    assert "imu" not in runs["vision"]
    first = np.loadtxt(tmp_path / "imu" / "trajectory.tum")[0]
    R = quaternions_to_rotations(first[4:8])[0]  # the first camera in the gravity-aligned world
    np.testing.assert_allclose(R, imu["R_aligned_world"], atol=1e-9)
    down = R @ (SYNTHETIC_GRAVITY / 9.80665)  # the synthetic world's true gravity, in the output frame
    assert np.degrees(np.arccos(-down[2])) < 1.0
