"""Rig calibration (issue 21): the window's estimate of the right image's offset on shifted logs.

Every right image of a stereo sequence is shifted on load (:func:`gtvo.datasets.shifted.shift_right_images`,
``cv2.warpAffine`` bilinear, border replicated; nothing is written) and the odometry (window mode)
runs with and without the rig calibration. Per shift: the estimated offset and its sigma, the ATE
(SE(3)- and Sim(3)-aligned), the scale ratio (estimated / ground-truth path length) and the run time.
Figures and the command: docs/benchmarks.md, "Rig calibration".

    PYTHONPATH=. python benchmarks/rig_calibration.py [--sequence DIR] [--shifts "-3,0;-1.5,0;..."]
        [--cost-runs 2]

``--sequence`` also takes a KITTI *raw* drive folder (``image_00/data``, ``image_01/data``,
``calib_cam_to_cam.txt``; no ground truth), read by :func:`open_kitti_raw` here. ``--cost-runs N``
times N alternating runs without / with the rig calibration on the unshifted log (after one
warm-up run for the compiled kernels) and prints the ratio of their CPU and wall times.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from gtvo.config import OdometryConfig, SolverConfig  # noqa: E402
from gtvo.core.camera import PinholeCamera, StereoCamera  # noqa: E402
from gtvo.datasets._common import read_image  # noqa: E402
from gtvo.datasets.sequence import Sequence  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402
from gtvo.datasets.shifted import shift_right_images  # noqa: E402
from gtvo.evaluation.accuracy import evaluate, ground_truth  # noqa: E402
from gtvo.pipeline import process_sequence  # noqa: E402
from gtvo.window import WindowConfig  # noqa: E402

SHARED = Path(os.environ.get("GTVO_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
DEFAULT_SEQUENCE = SHARED / "kitti_stereo_sample" / "KITTI_sequence_1"
DEFAULT_SHIFTS = "0,0;-3,0;-1.5,0;-0.5,0;0.5,0;1.5,0;3,0;0,-1;0,1;1.5,1"


def open_kitti_raw(folder: Path) -> Sequence:
    """A KITTI raw "synced + rectified" drive (gray cameras 00/01) as a stereo :class:`Sequence`
    (intrinsics and baseline from ``P_rect_00``/``P_rect_01``; no ground truth)."""
    rows = {}
    for line in (folder / "calib_cam_to_cam.txt").read_text().splitlines():
        key, _, val = line.partition(":")
        if key in ("P_rect_00", "P_rect_01", "S_rect_00"):
            rows[key] = np.array(val.split(), dtype=float)
    P0, P1 = rows["P_rect_00"].reshape(3, 4), rows["P_rect_01"].reshape(3, 4)
    w, h = (int(x) for x in rows["S_rect_00"])
    cam = StereoCamera(PinholeCamera(P0[0, 0], P0[1, 1], P0[0, 2], P0[1, 2], w, h), -P1[0, 3] / P1[0, 0])
    left = sorted((folder / "image_00" / "data").glob("*.png"))
    right = sorted((folder / "image_01" / "data").glob("*.png"))
    stamps = np.array([np.datetime64(t.strip()).astype("datetime64[ns]").astype(np.int64) * 1e-9
                       for t in (folder / "image_00" / "timestamps.txt").read_text().splitlines() if t.strip()])
    return Sequence(folder.name, "stereo", cam, stamps - stamps[0], lambda i: read_image(left[i]),
                    lambda i: read_image(right[i]), source=folder, frame_names=[str(p) for p in left])


def open_any(path: str) -> Sequence:
    folder = Path(path)
    if (folder / "calib_cam_to_cam.txt").is_file():
        return open_kitti_raw(folder)
    return open_sequence(folder)


def cost_ratio(seq, runs: int, solver: str) -> str:
    """CPU and wall time of ``runs`` alternating runs without / with the rig calibration."""
    process_sequence(seq.truncated(3), OdometryConfig(solver=SolverConfig(window=solver)))  # compile the kernels
    cpu = {False: 0.0, True: 0.0}
    wall = {False: 0.0, True: 0.0}
    for _ in range(runs):
        for rig in (False, True):
            c, w = time.process_time(), time.perf_counter()
            config = OdometryConfig(solver=SolverConfig(window=solver), window=WindowConfig(rig_calibration=rig))
            process_sequence(seq, config,
                             warn=lambda m: None)
            cpu[rig] += time.process_time() - c
            wall[rig] += time.perf_counter() - w
    return (f"cost of the rig calibration, {runs} x 2 alternating runs: CPU {cpu[False]:.1f} s -> {cpu[True]:.1f} s "
            f"(ratio {cpu[True] / cpu[False]:.3f}), wall {wall[False]:.1f} s -> {wall[True]:.1f} s "
            f"(ratio {wall[True] / wall[False]:.3f})")


def run_one(seq, shift: tuple[float, float], rig: bool, solver: str) -> dict:
    """One odometry run on ``seq`` with its right images shifted by ``shift``."""
    s = shift_right_images(seq, shift) if any(shift) else seq
    cfg = OdometryConfig(solver=SolverConfig(window=solver), window=WindowConfig(rig_calibration=rig))
    warnings: list[str] = []
    try:
        vo, traj, info = process_sequence(s, cfg, warn=warnings.append)
    except Exception as exc:  # noqa: BLE001 - a failed run is a row, not a crash
        return {"shift": list(shift), "rig": rig, "error": str(exc)}
    row = {"shift": list(shift), "rig": rig, "seconds": info["seconds"], "frames": info["frames"],
           "failures": info["tracking_failures"], "warnings": warnings,
           "rig_offset_px": info.get("rig_offset_px"), "rig_offset_sigma_px": info.get("rig_offset_sigma_px"),
           "rig_offset_marginal_sigma_px": info.get("rig_offset_marginal_sigma_px"),
           "rig_offset_x_estimated": info.get("rig_offset_x_estimated"),
           "rig_initial_delta_y_px": info.get("rig_initial_delta_y_px")}
    pair = ground_truth(s, traj)
    if pair is not None:
        m = evaluate(*pair)
        row.update({k: m.get(k) for k in ("ate_rmse_m", "ate_sim3_rmse_m", "scale_ratio")})
    return row


def fmt(x, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def pair(v) -> str:
    """A (x, y) sigma pair, '-' for a missing one."""
    return "-" if v is None else ", ".join(fmt(x, ".3f") for x in v)


def table(rows: list[dict]) -> str:
    head = ("| shift (x, y) px | rig | estimate (x, y) px | x released | error bar (x, y) px | marginal sigma (x, y) px "
            "| ATE m | Sim(3) ATE m | scale | s |\n"
            "|---|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['shift'][0]:+g}, {r['shift'][1]:+g} | {'on' if r['rig'] else 'off'} | "
                         f"failed: {r['error']} | | | | | | | |")
            continue
        est = r.get("rig_offset_px")
        sig = r.get("rig_offset_sigma_px")
        msig = r.get("rig_offset_marginal_sigma_px")
        lines.append(
            f"| {r['shift'][0]:+g}, {r['shift'][1]:+g} | {'on' if r['rig'] else 'off'} | "
            f"{'-' if est is None else f'{est[0]:+.2f}, {est[1]:+.2f}'} | "
            f"{'-' if est is None else ('yes' if r.get('rig_offset_x_estimated') else 'no')} | {pair(sig)} | {pair(msig)} | "
            f"{fmt(r.get('ate_rmse_m'), '.4f')} | "
            f"{fmt(r.get('ate_sim3_rmse_m'), '.4f')} | {fmt(r.get('scale_ratio'), '.4f')} | {r['seconds']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", default=str(DEFAULT_SEQUENCE))
    ap.add_argument("--shifts", default=DEFAULT_SHIFTS, help="'sx,sy;sx,sy;...' right-image shifts (px)")
    ap.add_argument("--solver", default="gtsam", choices=("gtsam", "handrolled"))
    ap.add_argument("--baseline-runs", default="0,0;1.5,0", help="shifts also run without the rig calibration")
    ap.add_argument("--json", default=None, help="write the rows here")
    ap.add_argument("--cost-runs", type=int, default=0, help="time N alternating runs off/on (unshifted)")
    args = ap.parse_args(argv)
    seq = open_any(args.sequence)
    if args.cost_runs > 0:
        print(cost_ratio(seq, args.cost_runs, args.solver), flush=True)
    shifts = [tuple(float(x) for x in s.split(",")) for s in args.shifts.split(";") if s]
    plain = [tuple(float(x) for x in s.split(",")) for s in args.baseline_runs.split(";") if s]
    if args.cost_runs > 0 and not args.shifts:
        return 0
    rows = []
    t0 = time.perf_counter()
    for sh in plain:
        rows.append(run_one(seq, sh, False, args.solver))
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    for sh in shifts:
        rows.append(run_one(seq, sh, True, args.solver))
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    print(f"\n{seq.name}, solver {args.solver}, {time.perf_counter() - t0:.0f} s\n")
    print(table(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
