"""``gtvo demo``: the whole pipeline on gtvo's own synthetic stereo sequence (no data needed)."""

from __future__ import annotations

import argparse

from gtvo.commands._common import add_odometry_options, describe_solvers, odometry_config, print_report
from gtvo.commands._viewer import add_viewer_options, viewer_observers
from gtvo.core.interrupt import outputs_in_place
from gtvo.errors import InputError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo", help="run the pipeline on a generated synthetic stereo sequence with exact ground truth",
        description="Render gtvo's deterministic synthetic stereo sequence (docs/synthetic.md), run the same "
                    "pipeline as `gtvo run` on it, write the same outputs and print the metrics.")
    p.add_argument("--out", metavar="DIR", default="gtvo_out/demo", help="output folder (default gtvo_out/demo)")
    p.add_argument("--frames", type=int, default=40, help="number of stereo pairs (default 40)")
    p.add_argument("--noise-sigma", type=float, default=1.0, help="image noise in gray levels (default 1)")
    p.add_argument("--exposure-change", action="store_true", help="vary the exposure from frame to frame")
    add_odometry_options(p, demo_defaults())
    add_viewer_options(p)
    p.set_defaults(func=main)


def demo_defaults():
    """The library's settings with 800 points per keyframe: the synthetic scene's low-texture
    walls need more points than real images for the same accuracy."""
    from gtvo.config import FrontendConfig, OdometryConfig  # noqa: PLC0415

    return OdometryConfig(frontend=FrontendConfig(points_per_keyframe=800))


def main(args: argparse.Namespace) -> int:
    from gtvo.pipeline import run  # noqa: PLC0415
    from gtvo.datasets.synthetic import make_synthetic_sequence  # noqa: PLC0415

    if args.frames < 1:
        raise InputError(f"--frames must be >= 1, got {args.frames}")
    config = odometry_config(args)
    seq = make_synthetic_sequence(n_frames=args.frames, noise_sigma=args.noise_sigma,
                                  exposure_change=args.exposure_change)
    with viewer_observers(args) as observers:
        report = run(seq, out=args.out, config=config, progress=not args.no_progress, observers=observers)
    outputs_in_place()  # the run has succeeded: a Ctrl-C while it prints its summary changes nothing
    print(f"gtvo demo: synthetic sequence, {len(seq)} frames {seq.pinhole.width}x{seq.pinhole.height} "
          f"({describe_solvers(report)})")
    print_report(report)
    return 0
