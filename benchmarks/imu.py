"""Stereo + IMU (docs/imu.md): accuracy with and without the IMU, black frames carried, gravity and
bias recovered, the cost.

* Synthetic logs with an IMU (200 Hz, EuRoC's ADIS16448 noise and bias walk, gyro bias
  ``(0.01, -0.02, 0.015)`` rad/s, accelerometer bias ``(0.05, -0.03, 0.08)`` m/s^2): a fast-turning
  one (``motion="swerve"``: yaw +-30 deg every 4 s, up to 47 deg/s) and a gentle one
  (``motion="forward"``), ``--frames`` frames at 10 Hz each; ATE with the IMU against vision only
  (``--no-imu``: the same run without ``Sequence.imu``).
* The gentle log with frames ``--blind`` black (a covered lens): frames lost, and the position error
  of the frames after the black stretch against the clean run's.
* Gravity's direction (against the synthetic world's) and the gyro bias (against the simulated one)
  after the run (``--frames`` / 10 s).
* The fast-turning log at every ``--step``-th frame (3: 3.3 Hz, 14 deg per frame).
* The shared EuRoC static frames (``$GTVO_SHARED_DATA/euroc_v101_static_stereo``): the gravity
  direction the IMU gives against the ground truth's orientation (EuRoC's world has z up).
* The cost: CPU seconds of the whole run with the IMU over without (tracker and window run
  single-threaded; on a shared machine the wall clock is noise).

Figures and the command: docs/benchmarks.md, "Stereo + IMU".

    PYTHONPATH=. python benchmarks/imu.py [--frames 100] [--blind 40,60] [--step 3] [--seeds 0,1,2]
        [--cases fast,gentle,black,sparse,euroc] [--json FILE]

Every synthetic case runs on the logs of ``--seeds`` (scene, texture and IMU noise) and reports
each seed's figures, their mean and their worst.
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

from gtvo.config import OdometryConfig  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402
from gtvo.datasets.sequence import Sequence  # noqa: E402
from gtvo.datasets.synthetic import make_synthetic_sequence  # noqa: E402
from gtvo.datasets.synthetic_imu import SYNTHETIC_GRAVITY, ImuSimulation  # noqa: E402
from gtvo.evaluation.accuracy import evaluate, ground_truth  # noqa: E402
from gtvo.pipeline import process_sequence  # noqa: E402

GYRO_BIAS = (0.01, -0.02, 0.015)
ACCEL_BIAS = (0.05, -0.03, 0.08)


def blacked_out(seq: Sequence, frames: set[int]) -> Sequence:
    """``seq`` with the left and right images of ``frames`` black (a covered lens)."""
    def blank(load):
        return lambda i: np.zeros_like(np.asarray(load(i))) if i in frames else load(i)
    assert seq.load_right is not None
    return dataclasses.replace(seq, load_left=blank(seq.load_left), load_right=blank(seq.load_right))


def run(seq: Sequence) -> dict[str, Any]:
    """One odometry run with the default settings: CPU time, ATE, frame outcomes, position error per
    frame (in the first camera's world, as the ground truth), the IMU's state."""
    c0 = time.process_time()
    vo, traj, info = process_sequence(seq, OdometryConfig(), warn=lambda m: None)
    cpu = time.process_time() - c0
    pair = ground_truth(seq, traj)
    assert pair is not None
    est, ref = pair
    err = np.linalg.norm(traj.poses[:, :3, 3] - np.asarray(seq.gt_poses)[:, :3, 3], axis=1)
    outcomes = {k: (len(v) if isinstance(v, list) else v) for k, v in info["frame_outcomes"].items()}
    return {"cpu_seconds": cpu, "ate_m": evaluate(est, ref)["ate_rmse_m"], "outcomes": outcomes, "error_m": err,
            "imu": info.get("imu"), "window_seconds_mean": info.get("window_seconds_mean"), "poses": traj.poses}


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _log(motion: str, frames: int, seed: int, step: int = 1) -> Sequence:
    """The synthetic log with its IMU: scene, texture and IMU noise from ``seed``; every ``step``-th frame."""
    seq = make_synthetic_sequence(frames, width=320, height=240, motion=motion, seed=seed,
                                  imu=ImuSimulation(gyro_bias=GYRO_BIAS, accel_bias=ACCEL_BIAS, seed=seed))
    return seq if step == 1 else seq.subsampled(step)


def over_seeds(rows: list[dict[str, Any]], keys: tuple[str, ...]) -> dict[str, Any]:
    """The mean and the worst (largest) of ``keys`` over the seeds' ``rows``."""
    return {k: {"mean": float(np.mean([r[k] for r in rows])), "worst": float(np.max([r[k] for r in rows]))}
            for k in keys}


def synthetic(motion: str, frames: int, seeds: list[int], step: int = 1) -> dict[str, Any]:
    """With the IMU and without on the log of each seed (every ``step``-th frame): ATE, their ratio,
    gravity's direction error, the gyro bias's error, the CPU ratio; per seed, mean and worst."""
    rows = []
    for seed in seeds:
        seq = _log(motion, frames, seed, step)
        vision = run(dataclasses.replace(seq, imu=None))
        inertial = run(seq)
        imu = inertial["imu"]
        gyro = np.asarray(imu["gyro_bias"])
        row = {"seed": seed, "ate_vision_m": vision["ate_m"], "ate_imu_m": inertial["ate_m"],
               "ate_ratio": inertial["ate_m"] / vision["ate_m"],
               "end_error_vision_m": float(vision["error_m"][-1]), "end_error_imu_m": float(inertial["error_m"][-1]),
               "gravity_error_deg": angle_deg(np.asarray(imu["gravity_world"]), SYNTHETIC_GRAVITY),
               "gravity_sigma_deg": imu["gravity_sigma_deg"],
               "gyro_bias": gyro.round(5).tolist(), "gyro_bias_sigma": imu["gyro_bias_sigma"],
               "gyro_bias_error_relative": float(np.linalg.norm(gyro - GYRO_BIAS) / np.linalg.norm(GYRO_BIAS)),
               "accel_bias": np.round(imu["accel_bias"], 4).tolist(),
               "cpu_ratio": inertial["cpu_seconds"] / vision["cpu_seconds"],
               "outcomes_vision": vision["outcomes"], "outcomes_imu": inertial["outcomes"]}
        print(json.dumps(row), flush=True)
        rows.append(row)
    out = {"case": f"synthetic {motion}, {frames} frames at 10 Hz" + (f", every {step}th" if step > 1 else "")
           + ", IMU 200 Hz", "seeds": rows,
           **over_seeds(rows, ("ate_ratio", "gravity_error_deg", "gyro_bias_error_relative", "cpu_ratio"))}
    print(json.dumps({k: v for k, v in out.items() if k != "seeds"}), flush=True)
    return out


def blind(frames: int, blind_range: tuple[int, int], seeds: list[int]) -> dict[str, Any]:
    """The gentle log of each seed with ``blind_range`` black: frames lost, the position error after
    the black stretch against the clean run's; per seed, mean and worst."""
    rows = []
    dark_frames = set(range(*blind_range))
    after = slice(blind_range[1], None)
    for seed in seeds:
        seq = _log("forward", frames, seed)
        clean = run(seq)
        dark = run(blacked_out(seq, dark_frames))
        dark_vision = run(blacked_out(dataclasses.replace(seq, imu=None), dark_frames))
        row = {"seed": seed, "lost_imu": dark["outcomes"]["lost"], "imu_carried": dark["outcomes"]["imu_carried"],
               "lost_vision": dark_vision["outcomes"]["lost"],
               "error_after_mean_m": float(dark["error_m"][after].mean()),
               "error_after_mean_clean_m": float(clean["error_m"][after].mean()),
               "error_after_ratio": float(dark["error_m"][after].mean() / clean["error_m"][after].mean()),
               "error_after_mean_vision_m": float(dark_vision["error_m"][after].mean()),
               "blind_error_max_m": float(dark["error_m"][blind_range[0]:blind_range[1]].max()),
               "ate_blind_m": dark["ate_m"], "ate_blind_vision_m": dark_vision["ate_m"], "ate_clean_m": clean["ate_m"]}
        print(json.dumps(row), flush=True)
        rows.append(row)
    out = {"case": f"synthetic forward, {frames} frames, frames {blind_range[0]}..{blind_range[1] - 1} black",
           "seeds": rows, **over_seeds(rows, ("lost_imu", "error_after_ratio", "blind_error_max_m"))}
    print(json.dumps({k: v for k, v in out.items() if k != "seeds"}), flush=True)
    return out


def euroc() -> dict[str, Any] | None:
    root = Path(os.environ.get("GTVO_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    root = root / "euroc_v101_static_stereo"
    if not root.is_dir():
        print(f"(no {root}: EuRoC skipped)")
        return None
    seq = open_sequence(root)
    vo, _, info = process_sequence(seq, OdometryConfig(), warn=lambda m: None)
    g = np.asarray(info["imu"]["gravity_world"])  # in the first (rectified left) camera's frame
    g_truth_world = seq.gt_poses[0][:3, :3] @ g  # EuRoC's ground-truth world: z up
    out = {"case": f"EuRoC V1_01 static, {len(seq)} frames, {len(seq.imu)} IMU readings",
           "initialised": info["imu"]["initialised"],
           "gravity_error_deg": angle_deg(g_truth_world, np.array([0.0, 0.0, -1.0])),
           "gravity_sigma_deg": info["imu"]["gravity_sigma_deg"]}
    print(json.dumps(out), flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=100, help="frames of each synthetic log (10 Hz)")
    p.add_argument("--blind", default="40,60", help="the black frames, first,end (end excluded)")
    p.add_argument("--step", type=int, default=3, help="the sparse case: the fast-turning log at every STEP-th frame")
    p.add_argument("--seeds", default="0,1,2", help="the synthetic logs' seeds (scene, texture, IMU noise)")
    p.add_argument("--cases", default="fast,gentle,black,sparse,euroc", help="which cases to run")
    p.add_argument("--json", default=None, help="also write the figures to this file")
    a = p.parse_args(argv)
    first, end = (int(x) for x in a.blind.split(","))
    seeds = [int(x) for x in a.seeds.split(",")]
    cases = {
        "fast": ("fast_turns", lambda: synthetic("swerve", a.frames, seeds)),
        "gentle": ("gentle", lambda: synthetic("forward", a.frames, seeds)),
        "black": ("black_frames", lambda: blind(a.frames, (first, end), seeds)),
        "sparse": ("sparse_fast_turns", lambda: synthetic("swerve", a.frames, seeds, a.step)),
        "euroc": ("euroc_static", euroc),
    }
    run(_log("swerve", 15, 0))  # the process's first run compiles the kernels: not in any CPU ratio
    figures: dict[str, Any] = {cases[c][0]: cases[c][1]() for c in a.cases.split(",")}
    if a.json:
        Path(a.json).write_text(json.dumps(figures, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
