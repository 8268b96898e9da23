"""``gtvo calibrate-odometry ODOM REFERENCE``: fit raw odometry motions to reference motions."""

from __future__ import annotations

import argparse
import json

import numpy as np

from gtvo.core.paths import check_not_an_input
from gtvo.core.atomic import check_output_file
from gtvo.wheel_calibration import calibrate, read_motion_pair
from gtvo.wheel_calibration.plot import plot_trajectories


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``calibrate-odometry`` subcommand."""
    p = subparsers.add_parser(
        "calibrate-odometry", help="calibrate odometry against reference motions (linear 3x3 or diff-drive)",
        description="Fit raw odometry motions (dx dy dtheta per row, '#' comments; the Freiburg/Octave text "
                    "format or a plain table) to reference motions of the same rows.")
    p.add_argument("odom", help="raw odometry motions file")
    p.add_argument("reference", help="reference motions file (e.g. scan matching)")
    p.add_argument("--model", choices=("linear", "diff-drive"), default="linear",
                   help="linear: a 3x3 matrix X with reference = X odometry (least squares); diff-drive: left and "
                        "right wheel scales and the baseline of a differential drive; default linear")
    p.add_argument("--solver", choices=("handrolled", "gtsam"), default="handrolled",
                   help="handrolled: closed-form / Gauss-Newton in numpy; gtsam: the same fit as a GTSAM factor "
                        "graph; default handrolled")
    p.add_argument("--baseline", type=float, default=1.0,
                   help="nominal wheel baseline in metres (diff-drive model; default 1.0)")
    p.add_argument("--plot", metavar="OUT.png", help="write the raw/calibrated/reference trajectories as PNG")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the calibration; print text or JSON; optionally plot."""
    if args.plot:
        check_not_an_input(args.plot, {"odometry file": args.odom, "reference file": args.reference}, "--plot")
        check_output_file(args.plot)
    odom, ref = read_motion_pair(args.odom, args.reference)
    result = calibrate(odom, ref, model=args.model, solver=args.solver, nominal_baseline=args.baseline)
    if args.plot:
        plot_trajectories(args.plot, {"raw odometry": odom, f"calibrated ({args.model})": result.apply(odom),
                                      "reference": ref}, title=f"Odometry calibration ({args.model}, {len(odom)} motions)")
    out = result.to_dict()
    if args.json:
        print(json.dumps(out, allow_nan=False))
        return 0
    np.set_printoptions(precision=6, suppress=True)
    print(f"model: {out['model']} (solver {out['solver']}, {len(odom)} motions)")
    if out["model"] == "linear":
        print(f"X =\n{np.array(out['X'])}\ndet X = {out['det_X']:.6f}")
        print(f"standard errors =\n{np.array(out['standard_errors'])}")
    else:
        print(f"k_L = {out['left_wheel_scale']:.6f}  k_R = {out['right_wheel_scale']:.6f}  "
              f"k_b = {out['baseline_scale']:.6f}  (baseline {out['baseline']:.6f} m of nominal {out['nominal_baseline']} m)")
        print(f"standard errors = {np.array(out['standard_errors'])}")
    r = out["residuals"]
    print("residual rms (dx, dy, dtheta) = " + ", ".join(f"{v:.6g}" for v in r["rms"].values())
          + f"; sigma = {r['sigma']:.6g} over {r['dof']} dof")
    if args.plot:
        print(f"plot: {args.plot}")
    return 0
