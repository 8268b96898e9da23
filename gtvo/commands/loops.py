"""``gtvo loops SEQUENCE``: place recognition over a logged sequence (every K-th frame a keyframe).

Prints the verified loops (query ``i``, matched ``j``, inliers, normalised score, the relative
pose ``T_i_j``'s translation and rotation, and its error against the ground truth when the
sequence has one); ``--json`` prints a JSON object instead, ``--out`` writes it (atomically).
The math is :mod:`gtvo.loops` (docs/loop_closure.md); this module is only the shell.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from typing import Any

import numpy as np

from gtvo.core.paths import check_not_an_input
from gtvo.core.atomic import check_output_file, write_json
from gtvo.commands._common import parse_floats
from gtvo.datasets import FORMATS, open_sequence
from gtvo.errors import InputError
from gtvo.loops import LoopCandidate, LoopDetectorConfig, detect_loops


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``loops`` subcommand."""
    p = subparsers.add_parser("loops", help="detect and verify loop closures among the keyframes of a sequence",
                              description="Place recognition over a logged sequence (every K-th frame a keyframe): "
                                          "print the verified loops, or a JSON object with --json.")
    p.add_argument("sequence", help="a dataset folder or a ROS bag (any --format layout)")
    p.add_argument("--format", default="auto", choices=("auto",) + FORMATS, help="dataset layout (default: auto)")
    p.add_argument("--max-frames", type=int, default=None, help="use only the first frames")
    p.add_argument("--camera", metavar="FX,FY,CX,CY", default=None, help="intrinsics for TUM folders")
    p.add_argument("--every", type=int, default=1, help="every K-th frame is a keyframe (default 1)")
    p.add_argument("--window", type=int, default=None,
                   help="temporal window: the last N keyframes are never loop candidates (default 10)")
    p.add_argument("--min-inliers", type=int, default=None, help="PnP inliers needed to accept (default 30)")
    p.add_argument("--json", action="store_true", help="print a JSON object instead of the table")
    p.add_argument("--out", default=None, help="write the JSON object to this file")
    p.add_argument("--strict", action="store_true", help="stop at an unreadable frame instead of skipping it")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _rotation_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _loop_record(loop: LoopCandidate, gt: np.ndarray | None) -> dict[str, Any]:
    rec = loop.to_dict()
    if gt is not None and np.isfinite(gt[loop.i, 0, 0]) and np.isfinite(gt[loop.j, 0, 0]):
        E = np.linalg.inv(np.linalg.inv(gt[loop.i]) @ gt[loop.j]) @ loop.T_i_j
        rec["error_translation_m"] = float(np.linalg.norm(E[:3, 3]))
        rec["error_rotation_deg"] = _rotation_deg(E[:3, :3])
    return rec


def run(args: argparse.Namespace) -> int:
    """Run the subcommand; returns the exit code."""
    if args.every < 1:
        raise InputError(f"--every must be >= 1, got {args.every}")
    if args.max_frames is not None and args.max_frames < 1:
        raise InputError(f"--max-frames must be >= 1, got {args.max_frames}")
    if args.window is not None and args.window < 0:
        raise InputError(f"--window must be >= 0, got {args.window}")
    options = {} if args.camera is None else {"camera": parse_floats(args.camera, 4, "--camera")}
    if args.out:
        check_not_an_input(args.out, {"sequence folder": args.sequence}, "--out")
        check_output_file(args.out)
    seq = open_sequence(args.sequence, format=args.format, max_frames=args.max_frames, **options)
    config = LoopDetectorConfig()
    if args.window is not None:
        config = replace(config, temporal_window=args.window)
    if args.min_inliers is not None:
        if args.min_inliers < 6:
            raise InputError(f"--min-inliers must be >= 6, got {args.min_inliers}")
        config = replace(config, verification=replace(config.verification, min_inliers=args.min_inliers))
    frames = range(0, len(seq), args.every)
    det, loops = detect_loops(seq, frames, config, progress=not (args.json or args.no_progress), strict=args.strict)
    gt = seq.gt_poses if seq.has_ground_truth else None
    added = set(det.indices)
    if not added:
        raise InputError(f"no frame of {len(frames)} could be read (each was skipped)", path=seq.source)
    result = {"sequence": seq.name, "keyframes": len(added), "temporal_window": config.temporal_window,
              "skipped_frames": [k for k in frames if k not in added],
              "loops": [_loop_record(c, gt) for c in loops]}
    if args.out:
        write_json(args.out, result)
    if args.json:
        print(json.dumps(result))
        return 0
    skipped = f" ({len(result['skipped_frames'])} unreadable frame(s) skipped)" if result["skipped_frames"] else ""
    print(f"{seq.name}: {len(added)} keyframes{skipped}, {len(loops)} verified loop(s)")
    if loops:
        header = f"{'i':>6} {'j':>6} {'inliers':>7} {'score':>6} {'|t| m':>8} {'rot deg':>8}"
        print(header + ("  err_t m  err_R deg" if gt is not None else ""))
        for c, rec in zip(loops, result["loops"]):
            line = (f"{c.i:>6} {c.j:>6} {c.inliers:>7} {c.score:>6.2f} {np.linalg.norm(c.T_i_j[:3, 3]):>8.3f} "
                    f"{_rotation_deg(c.T_i_j[:3, :3]):>8.2f}")
            if "error_translation_m" in rec:
                line += f"  {rec['error_translation_m']:>7.3f}  {rec['error_rotation_deg']:>9.2f}"
            print(line)
    return 0
