"""``gtvo batch SPEC --out DIR``: the same job on many logs, with a summary (docs/batch.md)."""

from __future__ import annotations

import argparse
import sys

from gtvo.commands._common import add_odometry_options, odometry_config
from gtvo.errors import InputError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``batch`` subcommand."""
    p = sub.add_parser(
        "batch", help="run many logs as `gtvo run` would, with a summary table and a comparison plot",
        description="Run every log of SPEC (a folder of sequence folders, or a YAML list of logs with optional "
                    "name, format and configuration overrides) as `gtvo run` would, into DIR/<name>/, and write "
                    "DIR/summary.json, DIR/summary.md and DIR/summary.png. A log that fails is reported and the "
                    "others go on. Exit code 1 when any log failed, 2 for a bad SPEC. See docs/batch.md.")
    p.add_argument("spec", metavar="SPEC", help="a folder holding the logs, or a YAML file listing them")
    p.add_argument("--out", metavar="DIR", required=True, help="output folder (one folder per log + summary)")
    p.add_argument("--jobs", type=int, metavar="N", default=None,
                   help="logs run at once (default: the number of cores); each worker runs BLAS single-threaded")
    p.add_argument("--ray", metavar="ADDRESS", default=None,
                   help="run the logs on Ray: 'auto' joins a running cluster, 'local' starts a local Ray with "
                        "--jobs CPUs, anything else is a cluster address; workers must see the logs and DIR under "
                        "the same paths (needs pip install \"gtvo[ray]\")")
    p.add_argument("--resume", action="store_true",
                   help="skip logs whose outputs in DIR are complete and were made by the same job")
    p.add_argument("--max-frames", type=int, metavar="N", default=None,
                   help="use only the first N frames of each log (a log's own max_frames wins)")
    p.add_argument("--frame-step", type=int, metavar="K", default=1,
                   help="use every K-th frame of each log (a log's own frame_step wins)")
    p.add_argument("--loop-closure", action="store_true", help="loop closure for every log, as gtvo run's")
    add_odometry_options(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    """Run the batch; print one line per failed log and the summary's place. Exit 1 if any log failed."""
    from gtvo.batching import batch  # noqa: PLC0415

    for flag, value in (("--max-frames", args.max_frames), ("--frame-step", args.frame_step), ("--jobs", args.jobs)):
        if value is not None and value < 1:
            raise InputError(f"{flag} must be >= 1, got {value}")
    if args.ray is not None and not args.ray.strip():
        raise InputError("--ray needs 'auto', 'local' or a cluster address")
    result = batch(args.spec, args.out, jobs=args.jobs, ray=args.ray, resume=args.resume,
                   progress=not args.no_progress, config=odometry_config(args), max_frames=args.max_frames,
                   frame_step=args.frame_step, loop_closure=args.loop_closure)
    done = len(result.rows) - len(result.failed)
    resumed = f" ({len(result.resumed)} resumed)" if result.resumed else ""
    print(f"gtvo batch: {done} of {len(result.rows)} logs done{resumed}, {len(result.failed)} failed")
    for row in result.rows:
        if row["status"] != "done":
            print(f"  failed {row['name']}: {row.get('error')}", file=sys.stdout)
    print(f"  summary in {result.summary['md']}")
    return 1 if result.failed else 0
