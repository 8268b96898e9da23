"""Wheel odometry in the window (issue 33 items 5-6): calibration recovered, blind stretches carried, cost.

* Synthetic ground robot (``motion="ground"``, a slalom with turns both ways, ``--frames`` frames):
  the robot's wheel odometry with a known calibration error (diff-drive arcs ``K_TRUE``, and the
  linear model's ``X_TRUE`` on its planar pose) and noise; the run with wheels against the same run
  without: the calibration's error against the truth, its sigmas, ATE with and without wheels.
* KITTI_sequence_1 with wheel odometry simulated from its ground truth (the base 1.65 m under the
  left camera, diff-drive arcs with ``K_TRUE`` over a 1.6 m nominal track, noise ``KITTI_NOISE``):
  the same recovery; then frames ``--blind`` blacked out: no frame lost, the error after them
  against the clean run's.
* The cost: CPU time of the run with wheels over the run without (KITTI, alternating, ``--cost-runs``;
  the tracker and the window run single-threaded, and on a shared machine the wall clock is noise).

Figures and the command: docs/benchmarks.md, "Wheel odometry".

    PYTHONPATH=. python benchmarks/wheel_odometry.py [--frames 320] [--blind 20,30] [--cost-runs 2] [--json FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from gtvo.config import WheelConfig, as_config  # noqa: E402
from gtvo.core.lie import rotations_to_quaternions  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402
from gtvo.datasets.sequence import Sequence  # noqa: E402
from gtvo.datasets.synthetic import make_synthetic_sequence  # noqa: E402
from gtvo.datasets.synthetic_robot import SYNTHETIC_BASE_TO_CAMERA, WheelSimulation  # noqa: E402
from gtvo.datasets.wheel import simulate_wheel_odometry  # noqa: E402
from gtvo.evaluation.accuracy import evaluate, ground_truth  # noqa: E402
from gtvo.pipeline import process_sequence  # noqa: E402

SHARED = Path(os.environ.get("GTVO_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
KITTI = SHARED / "kitti_stereo_sample" / "KITTI_sequence_1"
#: the true diff-drive calibration of the simulated wheels (k_L, k_R, k_b)
K_TRUE = (1.02, 0.97, 1.04)
#: the true linear calibration X (row-major): scale, a lateral crab and a heading drift per metre
X_TRUE = (1.02, 0.0, 0.0, 0.005, 1.0, 0.0, 0.01, 0.0, 0.97)
#: KITTI: the base on the ground 1.65 m under the left camera (:func:`kitti_base_to_camera`)
KITTI_CAMERA_HEIGHT = 1.65
KITTI_NOMINAL_TRACK = 1.6
KITTI_NOISE = 0.002  # m per wheel per frame
SYNTHETIC_NOISE = {"arcs": 0.0005, "pose": (0.0005, 0.0005, 0.0005)}


def kitti_base_to_camera(gt: np.ndarray) -> tuple[float, ...]:
    """``T_base_cam`` of a base on the road under the camera (``[x, y, z, qx, qy, qz, qw]``): its x
    along the car's mean direction of travel in the camera frame (KITTI_sequence_1's camera looks
    1.2 deg below it), z up (the camera's -y made orthogonal), the camera ``KITTI_CAMERA_HEIGHT`` above
    it. A base whose x is the camera's z instead would climb 2.5 cm per 1.2 m frame: the planar
    terms would then pull against the images (docs/window.md, "Wheel odometry")."""
    travel = np.sum([(np.linalg.inv(gt[i]) @ gt[i + 1])[:3, 3] for i in range(len(gt) - 1)], axis=0)
    x = travel / np.linalg.norm(travel)
    z = np.array([0.0, -1.0, 0.0]) - x * (-x[1])
    z /= np.linalg.norm(z)
    R_base_cam = np.stack([x, np.cross(z, x), z])  # rows: the base's axes in camera coordinates
    q = rotations_to_quaternions(R_base_cam[None])[0]
    return (0.0, 0.0, KITTI_CAMERA_HEIGHT, *(float(v) for v in q))


def blacked_out(seq: Sequence, frames: set[int]) -> Sequence:
    """``seq`` with the left and right images of ``frames`` black (a covered lens)."""
    def blank(load):
        return lambda i: np.zeros_like(np.asarray(load(i))) if i in frames else load(i)
    assert seq.load_right is not None
    return dataclasses.replace(seq, load_left=blank(seq.load_left), load_right=blank(seq.load_right))


def run(seq: Sequence, wheel: dict[str, Any]) -> dict[str, Any]:
    """One odometry run (default settings plus the ``wheel:`` section): wall time, ATE, frame outcomes,
    position error per frame and the calibration's report."""
    t0, c0 = time.perf_counter(), time.process_time()
    vo, traj, info = process_sequence(seq, as_config({"wheel": wheel}), warn=lambda m: None)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    pair = ground_truth(seq, traj)
    assert pair is not None
    est, ref = pair
    err = np.linalg.norm(traj.poses[:, :3, 3] - np.asarray(seq.gt_poses)[:, :3, 3], axis=1)
    outcomes = {k: (len(v) if isinstance(v, list) else v) for k, v in info["frame_outcomes"].items()}
    return {"seconds": seconds, "cpu_seconds": cpu, "ate_m": evaluate(est, ref)["ate_rmse_m"], "outcomes": outcomes,
            "error_m": err, "wheel_calibration": info.get("wheel_calibration")}


def recovery(report: dict[str, Any], truth: tuple[float, ...]) -> dict[str, Any]:
    """The estimate against the truth: per parameter the error (relative for the diff-drive scales,
    absolute for X's entries), the sigma and whether the run observed it."""
    if report["model"] == "linear":
        est = np.asarray(report["X"])
    else:
        est = np.array([report["left_wheel_scale"], report["right_wheel_scale"], report["track_width_scale"]])
    err = est - np.asarray(truth)
    if report["model"] == "diff_drive":
        err = err / np.asarray(truth)
    return {"estimate": est.round(5).tolist(), "error": err.round(5).tolist(), "sigma": report["sigmas"],
            "observed": report["observed"], "warning": report["warning"]}


def synthetic(frames: int) -> list[dict[str, Any]]:
    out = []
    for model, kind, truth in (("diff_drive", "arcs", K_TRUE), ("linear", "pose", X_TRUE)):
        sim = WheelSimulation(kind=kind, calibration=truth, noise=0.0 if kind == "pose" else SYNTHETIC_NOISE[kind])
        seq = make_synthetic_sequence(frames, width=320, height=240, step_m=0.1, motion="ground", wheels=sim)
        if kind == "pose":  # per-axis noise
            log = simulate_wheel_odometry(seq.timestamps, np.asarray(seq.gt_poses), sim.T_base_cam, "pose",
                                          np.asarray(truth).reshape(3, 3), SYNTHETIC_NOISE["pose"], 1)
            seq = dataclasses.replace(seq, wheel_odometry=dataclasses.replace(log, base_to_camera=sim.T_base_cam))
        wheel = {"model": model, "base_to_camera": list(SYNTHETIC_BASE_TO_CAMERA),
                 "nominal_baseline": sim.nominal_baseline}
        without = run(dataclasses.replace(seq, wheel_odometry=None), wheel)
        with_wheels = run(seq, wheel)
        out.append({"case": f"synthetic ground robot, {frames} frames, {model} ({kind})",
                    "recovery": recovery(with_wheels["wheel_calibration"], truth),
                    "ate_without_m": without["ate_m"], "ate_with_m": with_wheels["ate_m"],
                    "cpu_seconds_without": without["cpu_seconds"], "cpu_seconds_with": with_wheels["cpu_seconds"]})
        print(json.dumps(out[-1]), flush=True)
    return out


def kitti(blind: tuple[int, int], cost_runs: int) -> dict[str, Any]:
    seq = open_sequence(KITTI)
    base_to_camera = kitti_base_to_camera(np.asarray(seq.gt_poses))
    T_bc = WheelConfig(base_to_camera=base_to_camera).T_base_cam
    log = simulate_wheel_odometry(seq.timestamps, np.asarray(seq.gt_poses), T_bc, "arcs", K_TRUE, KITTI_NOISE, 2,
                                  nominal_baseline=KITTI_NOMINAL_TRACK, source="simulated from the ground truth")
    wheel = {"model": "diff_drive", "base_to_camera": list(base_to_camera), "nominal_baseline": KITTI_NOMINAL_TRACK}
    with_wheels = dataclasses.replace(seq, wheel_odometry=log)
    clean = run(with_wheels, wheel)
    frames = set(range(*blind))
    dark = run(blacked_out(with_wheels, frames), wheel)
    dark_without = run(blacked_out(seq, frames), wheel)
    after = slice(blind[1], None)
    times: dict[str, list[float]] = {"without": [], "with": []}
    for _ in range(cost_runs):  # CPU seconds (BLAS single-threaded): the wall clock of a shared machine is noise
        times["without"].append(run(seq, wheel)["cpu_seconds"])
        times["with"].append(run(with_wheels, wheel)["cpu_seconds"])
    out = {"case": f"KITTI_sequence_1, simulated wheels (k = {K_TRUE}, noise {KITTI_NOISE} m/frame)",
           "recovery": recovery(clean["wheel_calibration"], K_TRUE), "ate_with_m": clean["ate_m"],
           "blind_frames": f"{blind[0]}..{blind[1] - 1}", "blind_outcomes": dark["outcomes"],
           "blind_outcomes_without_wheels": dark_without["outcomes"],
           "blind_error_max_m": float(dark["error_m"][blind[0]:blind[1]].max()),
           "blind_error_max_without_wheels_m": float(dark_without["error_m"][blind[0]:blind[1]].max()),
           "after_error_minus_clean_max_m": float(np.max(dark["error_m"][after] - clean["error_m"][after])),
           "after_error_minus_clean_max_without_wheels_m":
               float(np.max(dark_without["error_m"][after] - clean["error_m"][after])),
           "ate_blind_m": dark["ate_m"], "ate_blind_without_wheels_m": dark_without["ate_m"],
           "cpu_seconds_without": times["without"], "cpu_seconds_with": times["with"],
           "cost_ratio": float(np.sum(times["with"]) / np.sum(times["without"])) if cost_runs else None}
    print(json.dumps(out), flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=320, help="frames of the synthetic ground robot's logs")
    p.add_argument("--blind", default="20,30", help="KITTI: the blacked-out frames, first,end (end excluded)")
    p.add_argument("--cost-runs", type=int, default=2, help="KITTI: alternating timed runs without / with wheels")
    p.add_argument("--skip-synthetic", action="store_true")
    p.add_argument("--json", type=Path, help="write the figures here")
    a = p.parse_args(argv)
    first, end = (int(x) for x in a.blind.split(","))
    results = {"kitti": kitti((first, end), a.cost_runs)}
    if not a.skip_synthetic:
        results["synthetic"] = synthetic(a.frames)
    if a.json is not None:
        a.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
