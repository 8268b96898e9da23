"""gtvo against the two peers a user would otherwise build, in one run on the same frames (issue 4, item 5).

    python benchmarks/kitti_vo.py [--sequence DIR ...] [--max-frames N] [--frame-step K]
                                  [--solvers handrolled,gtsam,default] [--modes track,...] [--peers open3d,orb]
                                  [--no-flow-fallback] [--json OUT] [--failure-detail]

Rows: gtvo for every requested solver x mode (a mode the installed gtvo lacks is skipped with a
note), then the peers of ``benchmarks/peers.py``: (a) SGBM + Open3D RGB-D odometry with the
colour term, (b) ORB + SGBM + solvePnPRansac. On an RGB-D sequence (TUM layout) the peers use the
sensor's depth instead of SGBM. Every row runs on the same frames, preloaded in memory, so the
timings count computation only; they are also given as multiples of a reference measured in the
same run (one OpenCV StereoSGBM of the first frame, median of 5, taken before and after the rows);
start-up is excluded (a short gtvo warm-up run first: numba loads its compiled loops at first call).

Columns (benchmarks/vo_bench.py): ATE RMSE after SE(3) alignment, drift % (first pose aligned;
'-' on a clip that does not move), the KITTI devkit's segment errors over 10-40 m segments from
every frame (translation %, rotation deg per 100 m), RPE over 1-frame pairs, max displacement
from the first position (must stay below 1 cm on the static EuRoC clip), ms/frame, its ratio to the reference,
frames/s, and for gtvo keyframes / tracking failures (peers: steps where their estimate failed).

``--frame-step K`` plays the log at 1/K of its frame rate (every K-th frame, the first one
included): on KITTI (10 Hz, 1.2 m/frame here) K = 2 and 3 are 2.4 and 3.6 m steps, i.e. the same
road driven at 86 and 130 km/h. A check of robustness to the motion per frame, not a new dataset.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.peers import Open3DColorOdometryPeer, OrbPnPPeer, run_peer  # noqa: E402
from benchmarks.vo_bench import (KITTI_SEQUENCE_1, ModeUnavailable, failure_details, fmt, gtvo_config,  # noqa: E402
                                 load_frames, markdown_table, reference_ms, run_gtvo, score)
from gtvo.core.atomic import write_json  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402

PEERS = {"open3d": Open3DColorOdometryPeer, "orb": OrbPnPPeer}
HEADER = ["method", "frames", "ATE RMSE (m)", "Sim(3) ATE (m)", "scale", "drift %", "seg t %", "seg r (deg/100 m)",
          "RPE t (m)", "RPE r (deg)",
          "max disp (m)", "ms/frame", "x ref", "frames/s", "keyframes", "failures"]


def _split(text: str) -> list[str]:
    return [p.strip() for p in text.split(",") if p.strip()]


def bench_sequence(path: Path, max_frames: int | None, solvers: list[str], modes: list[str], peers: list[str],
                   motion_model: str, progress: bool, o3d_gates: list[float | None] | None = None,
                   frame_step: int = 1, gtvo_overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Every row on one sequence; returns ``{"sequence", "reference_ms", "rows", "notes"}``."""
    seq = open_sequence(path, max_frames=max_frames).subsampled(frame_step)
    frames = load_frames(seq, progress)
    ref_before = reference_ms(frames)
    rows: list[dict[str, Any]] = []
    notes: list[str] = []
    # start-up excluded: the compiled loops are loaded from numba's cache (or compiled) at their
    # first call, about a second that the first row would otherwise carry
    for mode in modes:
        try:
            run_gtvo(seq.camera, frames[:4], gtvo_config(solvers[0] if solvers else "default", mode,
                                                         motion_model=motion_model, **(gtvo_overrides or {})))
        except ModeUnavailable:
            pass
    for mode in modes:
        for solver in solvers:
            label = f"gtvo {mode}, {solver}"
            try:
                config = gtvo_config(solver, mode, motion_model=motion_model, **(gtvo_overrides or {}))
            except ModeUnavailable as exc:
                notes.append(f"{label}: skipped ({exc})")
                continue
            print(f"  running {label} ...", file=sys.stderr, flush=True)
            g = run_gtvo(seq.camera, frames, config)
            rows.append({"method": label, "kind": "gtvo", "mode": mode, "solver": solver, "frames": len(frames),
                         "seconds": g["seconds"], "keyframes": g["keyframes"], "failures": g["failures"],
                         "tracking_iterations_mean": g["tracking_iterations_mean"],
                         "failure_reasons": g["failure_reasons"], "failure_details": failure_details(g["vo"], seq),
                         **score(g["trajectory"], seq)})
    runs: list[tuple[str, dict[str, Any]]] = []
    for name in peers:
        if name == "open3d":
            runs += [(name, {"depth_diff_max": g}) for g in (o3d_gates or [None])]
        else:
            runs.append((name, {}))
    for name, kwargs in runs:
        peer = PEERS[name](seq.camera, **kwargs)
        label = peer.name if seq.kind == "stereo" else peer.name.replace("SGBM", "sensor depth")
        if name == "open3d" and o3d_gates and len(o3d_gates) > 1:
            label += f", gate {peer.depth_diff_max:g} m"
        print(f"  running {label} ...", file=sys.stderr, flush=True)
        r = run_peer(peer, frames, label)
        row = {"method": label, "kind": "peer", "peer": name, "frames": len(frames), "seconds": r.seconds,
               "keyframes": None, "failures": r.failures, **score(r.trajectory, seq)}
        if name == "open3d":
            row["depth_diff_max_m"] = peer.depth_diff_max
        rows.append(row)
    ref_after = reference_ms(frames)
    ref = float(np.median([ref_before, ref_after]))
    for row in rows:
        row["ms_per_frame"] = 1000.0 * row["seconds"] / row["frames"]
        row["x_ref"] = row["ms_per_frame"] / ref
        row["frames_per_second"] = row["frames"] / row["seconds"]
    return {"sequence": str(path), "name": seq.name, "kind": seq.kind, "frames": len(frames), "frame_step": frame_step,
            "reference_ms": ref, "reference_ms_before_after": [ref_before, ref_after], "rows": rows,
            "notes": notes}


def table(result: dict[str, Any]) -> str:
    """The markdown table of one sequence's rows."""
    rows = [[r["method"], str(r["frames"]), fmt(r["ate_m"], ".3f"), fmt(r.get("ate_sim3_m"), ".3f"),
             fmt(r.get("scale"), ".4f"), fmt(r["drift_pct"], ".2f"),
             fmt(r["seg_t_pct"], ".2f"), fmt(r["seg_r_deg_per_100m"], ".2f"),
             fmt(r["rpe_t_m"], ".3f"), fmt(r["rpe_r_deg"], ".3f"), fmt(r["max_disp_m"], ".4f"),
             fmt(r["ms_per_frame"], ".0f"), fmt(r["x_ref"], ".2f"), fmt(r["frames_per_second"], ".2f"),
             fmt(r["keyframes"], "d"), fmt(r["failures"], "d")] for r in result["rows"]]
    return markdown_table(HEADER, rows)


def failure_summary(row: dict[str, Any], detail: bool) -> str:
    """gtvo's tracking failures of one row: reasons and, per failed frame, the kept (predicted)
    and the tracked pose's frame-to-frame error against the ground truth."""
    lines = [f"{row['method']}: {row['failures']} tracking failures"]
    lines += [f"  {n} x {reason}" for reason, n in row["failure_reasons"].items()]
    d = row["failure_details"]
    if d:
        keys = ("kept_t_m", "kept_r_deg", "tracked_t_m", "tracked_r_deg")
        mean = {k: float(np.mean([x[k] for x in d])) for k in keys}
        lines.append(f"  frame-to-frame error vs GT, mean over failed frames: kept pose (motion-model prediction) "
                     f"{mean['kept_t_m']:.3f} m / {mean['kept_r_deg']:.3f} deg; rejected tracked pose "
                     f"{mean['tracked_t_m']:.3f} m / {mean['tracked_r_deg']:.3f} deg")
    if detail and d:
        lines.append("")
        header = ["frame", "reason", "kept t (m)", "kept r (deg)", "tracked t (m)", "tracked r (deg)"]
        lines.append(markdown_table(header, [[str(x["frame"]), x["reason"]] + [f"{x[k]:.3f}" for k in keys]
                                             for x in d]))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", type=Path, action="append", default=None, metavar="DIR",
                    help=f"sequence folder (repeatable; default {KITTI_SEQUENCE_1})")
    ap.add_argument("--max-frames", type=int, default=None, metavar="N")
    ap.add_argument("--frame-step", type=int, default=1, metavar="K",
                    help="use every K-th frame (the log at 1/K of its frame rate)")
    ap.add_argument("--solvers", default="handrolled,gtsam",
                    help="gtvo solvers (comma-separated; 'default': the configuration's own, hand-rolled "
                         "tracker and GTSAM window, i.e. a plain `gtvo run`)")
    ap.add_argument("--modes", default="track,window", help="gtvo modes (comma-separated; missing ones are skipped)")
    ap.add_argument("--peers", default="open3d,orb", help="peers to run: open3d, orb (comma-separated; '' for none)")
    ap.add_argument("--o3d-depth-diff-max", default=None, metavar="LIST",
                    help="Open3D peer's depth gate(s) in m, comma-separated: one row each (default: the "
                         "peer's, 0.3 m for SGBM depth, 0.03 m for sensor depth)")
    ap.add_argument("--motion-model", default="constant-velocity", choices=("constant-velocity", "kalman"))
    ap.add_argument("--no-flow-fallback", action="store_true",
                    help="gtvo without the optical-flow fallback (OdometryConfig(flow_fallback=None))")
    ap.add_argument("--json", type=Path, default=None, metavar="OUT", help="also write all figures as JSON")
    ap.add_argument("--failure-detail", action="store_true", help="list gtvo's failed frames one by one")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    peers = _split(args.peers)
    bad = [p for p in peers if p not in PEERS]
    if bad:
        ap.error(f"unknown peer(s) {bad}: use {sorted(PEERS)}")
    results = []
    for path in args.sequence or [KITTI_SEQUENCE_1]:
        print(f"{path}:", file=sys.stderr, flush=True)
        gates = None if args.o3d_depth_diff_max is None else [float(g) for g in _split(args.o3d_depth_diff_max)]
        res = bench_sequence(path, args.max_frames, _split(args.solvers), _split(args.modes), peers,
                             args.motion_model, not args.no_progress, gates, args.frame_step,
                             {"flow_fallback": None} if args.no_flow_fallback else None)
        results.append(res)
        step = f", every {args.frame_step}th frame" if args.frame_step > 1 else ""
        print(f"\n### {res['name']} ({res['kind']}, {res['frames']} frames{step})\n")
        print(f"Reference: one StereoSGBM of frame 0 = {res['reference_ms']:.0f} ms "
              f"(before / after the rows: {res['reference_ms_before_after'][0]:.0f} / "
              f"{res['reference_ms_before_after'][1]:.0f} ms).\n")
        print(table(res))
        for note in res["notes"]:
            print(f"\nNote: {note}")
        for row in res["rows"]:
            if row["kind"] == "gtvo" and row["failures"]:
                print("\n" + failure_summary(row, args.failure_detail))
        sys.stdout.flush()
    if args.json is not None:
        write_json(args.json, {"command": " ".join(sys.argv), "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
