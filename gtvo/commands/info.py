"""``gtvo info``: what a log holds (a bag's topics, types, counts, rates) and what ``gtvo run``
would use from it (:func:`gtvo.datasets.info.describe_log`)."""

from __future__ import annotations

import argparse
import json

from gtvo.commands._bag import add_bag_options, bag_options
from gtvo.datasets import FORMATS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "info", help="a log's topics and what `gtvo run` would use from it",
        description="Print a log's topics, types, message counts and rates (ROS bags), and the sequence "
                    "`gtvo run` would read with the same options: image topics, frames, camera, ground truth, "
                    "unpaired messages; or the one-line reason it would fail. Exit 0 when the log could be "
                    "read, 2 when it cannot (missing, truncated or corrupt).")
    p.add_argument("log", metavar="LOG", help="a sequence folder, a .bag file or a ROS2 bag folder")
    p.add_argument("--format", choices=("auto",) + FORMATS, default="auto",
                   help="dataset layout (default: auto-detect)")
    p.add_argument("--json", action="store_true", help="print the description as JSON")
    add_bag_options(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from gtvo.datasets.info import describe_log  # noqa: PLC0415

    info = describe_log(args.log, format=args.format, **bag_options(args))
    print(json.dumps(info.to_dict(), indent=2) if args.json else "\n".join(info.lines()))
    return 0
