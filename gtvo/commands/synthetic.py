"""``gtvo synthetic --out DIR``: write the synthetic stereo sequence in the KITTI odometry layout."""

from __future__ import annotations

import argparse

from gtvo.errors import InputError
from gtvo.datasets.synthetic import MAX_SIDE, MIN_SIDE, make_synthetic_sequence, write_sequence_kitti


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``synthetic`` subcommand."""
    p = subparsers.add_parser(
        "synthetic", help="write the synthetic stereo sequence (exact poses) as a KITTI-layout folder",
        description="Render gtvo's deterministic synthetic stereo sequence (docs/synthetic.md) and write it as "
                    "calib.txt, image_0/, image_1/ (8-bit PNG), times.txt and poses.txt (ground truth).")
    p.add_argument("--out", required=True, help="output folder: created, or replaced as a whole when it holds only a sequence written here "
                        "(anything else in it is refused)")
    p.add_argument("--frames", type=int, default=30, help="number of stereo pairs at 10 Hz (default 30)")
    p.add_argument("--width", type=int, default=320, help="image width in pixels (default 320)")
    p.add_argument("--height", type=int, default=240, help="image height in pixels (default 240)")
    p.add_argument("--motion", choices=("forward", "loop", "turn"), default="forward",
                   help="camera path: forward with wobbles (default), an elliptic loop, or a car's right turn")
    p.add_argument("--noise-sigma", type=float, default=0.0, help="Gaussian image noise in gray levels")
    p.add_argument("--exposure-change", action="store_true", help="apply the known per-frame affine brightness")
    p.add_argument("--seed", type=int, default=0, help="seed of textures, box layout and noise (default 0)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Render and write the sequence; print where it went."""
    if args.frames < 1:
        raise InputError(f"--frames must be >= 1, got {args.frames}")
    if not (MIN_SIDE <= args.width <= MAX_SIDE and MIN_SIDE <= args.height <= MAX_SIDE):
        raise InputError(f"--width and --height must be between {MIN_SIDE} and {MAX_SIDE}, got {args.width}x{args.height}")
    seq = make_synthetic_sequence(n_frames=args.frames, width=args.width, height=args.height, motion=args.motion,
                                  noise_sigma=args.noise_sigma, exposure_change=args.exposure_change, seed=args.seed)
    out = write_sequence_kitti(seq, args.out, progress=not args.no_progress)
    print(f"wrote {len(seq)} stereo pairs ({seq.pinhole.width}x{seq.pinhole.height}, {args.motion}) to {out}")
    return 0
