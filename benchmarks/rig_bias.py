"""Where the rig offset's scale bias comes from (issue 30): rendered offsets with exact ground truth.

Two experiments, each run with the rig calibration off and on (window mode, default settings):

* ``synthetic``: the synthetic room (:func:`gtvo.datasets.synthetic.make_synthetic_sequence`) with the
  right camera *rendered* with its principal point moved by ``(dx, dy)`` px
  (``right_principal_offset``): the true offset is exact and no image is resampled.
* ``kitti``: a KITTI sequence with its right images *resampled* by ``(sx, sy)`` px on load
  (:func:`gtvo.datasets.shifted.shift_right_images`), as ``benchmarks/rig_calibration.py``.

Per run it prints the estimated offset against the true one (for KITTI the shift added to the
rig's own, unknown offset), the Sim(3) scale of the estimate against the ground truth (Umeyama;
1 = right scale), the path-length ratio, and the SE(3) / Sim(3) ATE.

    PYTHONPATH=. python benchmarks/rig_bias.py synthetic [--seeds 0,1,2] [--offsets "0,0;1,0;-2,0.5"]
        [--frames 60] [--supersample 1] [--rig off,on] [--json out.json]
    PYTHONPATH=. python benchmarks/rig_bias.py kitti [--sequence DIR] [--shifts "0,0;1.5,0;..."] [--frame-step N]
        [--interpolation linear|cubic|lanczos4] [--release-at-first-test]

``--stereo-sampling`` sets :attr:`gtvo.frontend.stereo_types.StereoSearchConfig` fields for the
targeted measurements of docs/window.md ("Rig calibration", "Where the bias comes from").
Figures and commands: docs/benchmarks.md, "Rig calibration".
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from benchmarks.rig_calibration import DEFAULT_SEQUENCE, open_any  # noqa: E402
from gtvo.config import OdometryConfig  # noqa: E402
import gtvo.window.rig as rig_module  # noqa: E402
from gtvo.datasets.shifted import shift_right_images  # noqa: E402
from gtvo.datasets.synthetic import make_synthetic_sequence  # noqa: E402
from gtvo.evaluation.alignment import umeyama_alignment  # noqa: E402
from gtvo.evaluation.accuracy import evaluate, ground_truth  # noqa: E402
from gtvo.pipeline import process_sequence  # noqa: E402
from gtvo.window import WindowConfig  # noqa: E402

SYNTHETIC_OFFSETS = "0,0;2,0;-2,0;1,0;-1,0;0.5,0;0,1;0,-0.5;1.5,-1;-0.7,2"
KITTI_SHIFTS = "0,0;1.5,0;-1.5,0;0,0.5;0,-0.5;1.5,0.5;-1.5,-0.5"


def parse_pairs(text: str) -> list[tuple[float, float]]:
    """``"x,y;x,y"`` -> [(x, y), ...]."""
    return [tuple(float(v) for v in s.split(",")) for s in text.split(";") if s.strip()]  # type: ignore[misc]


def sim3_scale(est_positions: np.ndarray, gt_positions: np.ndarray) -> float:
    """The estimate's scale against the ground truth: 1 / s of the Umeyama Sim(3) ``gt = s R est + t``."""
    return 1.0 / umeyama_alignment(est_positions, gt_positions, with_scale=True).scale


def run_one(seq, rig: bool, true_offset: tuple[float, float], label: str) -> dict:
    """One window run of ``seq``; the row of the table."""
    cfg = OdometryConfig(window=WindowConfig(rig_calibration=rig))
    t0 = time.process_time()
    try:
        vo, traj, info = process_sequence(seq, cfg, warn=lambda m: None)
    except Exception as exc:  # noqa: BLE001 - a failed run is a row
        return {"label": label, "rig": rig, "true": list(true_offset), "error": str(exc)}
    row = {"label": label, "rig": rig, "true": list(true_offset), "cpu_s": time.process_time() - t0,
           "failures": info["tracking_failures"], "path_m": traj.path_length(), "rig_offset_px": info.get("rig_offset_px"),
           "x_released": info.get("rig_offset_x_estimated"), "x_tested_px": info.get("rig_offset_x_tested_px")}
    test = None if vo.window is None or vo.window.rig is None else vo.window.rig.test
    row["tested_px"] = None if test is None else [float(v) for v in test[0]]
    pair = ground_truth(seq, traj)
    if pair is not None:
        m = evaluate(*pair)
        row.update({k: m.get(k) for k in ("ate_rmse_m", "ate_sim3_rmse_m", "scale_ratio")})
        row["sim3_scale"] = sim3_scale(pair[0].positions, pair[1].positions)
    return row


def fmt(x, spec: str) -> str:
    return "-" if x is None else format(x, spec)


HEAD = ("| run | rig | true (x, y) px | estimate (x, y) px | x released | Sim(3) scale | path ratio | path m | ATE m "
        "| Sim(3) ATE m | CPU s |\n|---|---|---|---|---|---|---|---|---|---|---|")


def line(r: dict) -> str:
    t = f"{r['true'][0]:+.2f}, {r['true'][1]:+.2f}"
    if "error" in r:
        return f"| {r['label']} | {'on' if r['rig'] else 'off'} | {t} | failed: {r['error']} | | | | | | | |"
    e = r.get("rig_offset_px")
    est = "-" if e is None else f"{e[0]:+.3f}, {e[1]:+.3f}"
    t2 = r.get("tested_px")
    tested = fmt(r.get("x_tested_px"), "+.3f") if not t2 else f"{t2[0]:+.3f}, {t2[1]:+.3f}"
    rel = "-" if e is None else ("yes" if r.get("x_released") else f"no ({tested})")
    return (f"| {r['label']} | {'on' if r['rig'] else 'off'} | {t} | {est} | {rel} | {fmt(r.get('sim3_scale'), '.4f')} | "
            f"{fmt(r.get('scale_ratio'), '.4f')} | {r['path_m']:.3f} | {fmt(r.get('ate_rmse_m'), '.4f')} | "
            f"{fmt(r.get('ate_sim3_rmse_m'), '.4f')} | {r['cpu_s']:.1f} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("experiment", choices=("synthetic", "kitti"))
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--offsets", default=SYNTHETIC_OFFSETS, help="synthetic: rendered right principal-point offsets")
    ap.add_argument("--frames", type=int, default=60, help="synthetic: frames per log")
    ap.add_argument("--supersample", type=int, default=1,
                    help="synthetic: rays per pixel side (1: point sampling; more: area-integrated pixels)")
    ap.add_argument("--sequence", default=str(DEFAULT_SEQUENCE), help="kitti: the sequence (or a raw drive)")
    ap.add_argument("--shifts", default=KITTI_SHIFTS, help="kitti: resampled right-image shifts")
    ap.add_argument("--max-frames", type=int, default=0, help="kitti: first N frames only (0: all)")
    ap.add_argument("--frame-step", type=int, default=1, help="kitti: every N-th frame (the log at 1/N its rate)")
    ap.add_argument("--rig", default="off,on", help="calibration settings to run: off, on or both")
    ap.add_argument("--interpolation", default="linear", choices=("linear", "cubic", "lanczos4"),
                    help="kitti: how the right images are resampled (linear also blurs them)")
    ap.add_argument("--release-at-first-test", action="store_true",
                    help="diagnostic: release the offset at its first test whatever it says (significance 0)")
    ap.add_argument("--json", default=None, help="write the rows here")
    args = ap.parse_args(argv)
    rigs = [s.strip() == "on" for s in args.rig.split(",") if s.strip()]
    if args.release_at_first_test:
        rig_module.RIG_SIGNIFICANCE = 0.0
    rows: list[dict] = []
    print(HEAD, flush=True)
    if args.experiment == "synthetic":
        for seed in (int(s) for s in args.seeds.split(",")):
            for off in parse_pairs(args.offsets):
                seq = make_synthetic_sequence(args.frames, seed=seed, right_principal_offset=off,
                                              supersample=args.supersample)
                for rig in rigs:
                    rows.append(run_one(seq, rig, off, f"seed {seed}"))
                    print(line(rows[-1]), flush=True)
    else:
        base = open_any(args.sequence)
        if args.max_frames:
            base = base.truncated(args.max_frames)
        if args.frame_step > 1:
            base = base.subsampled(args.frame_step)
        for sh in parse_pairs(args.shifts):
            seq = shift_right_images(base, sh, args.interpolation) if any(sh) else base
            for rig in rigs:
                rows.append(run_one(seq, rig, sh, base.name))
                print(line(rows[-1]), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
