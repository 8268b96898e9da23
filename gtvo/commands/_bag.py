"""Options of ROS bag input shared by ``gtvo run`` and ``gtvo info``."""

from __future__ import annotations

import argparse
import math
from typing import Any

from gtvo.datasets.bag_types import RGBD_TOLERANCE_S, STEREO_TOLERANCE_S
from gtvo.errors import InputError


def add_bag_options(p: argparse.ArgumentParser) -> None:
    """``--calib``, ``--left-topic``, ``--right-topic``, ``--depth-topic``, ``--ground-truth-topic``,
    ``--stamp-tolerance`` (the pairing tolerance the unpaired-messages warning names)."""
    g = p.add_argument_group("ROS bags (.bag file or ROS2 bag folder)")
    g.add_argument("--calib", metavar="FILE", default=None,
                   help="calibration instead of the bag's CameraInfo: KITTI calib.txt, EuRoC cam0 sensor.yaml, "
                        "or a YAML of left:/right: camera_info blocks (docs/datasets.md)")
    g.add_argument("--left-topic", metavar="TOPIC", default=None, help="left (or RGB-D colour) image topic")
    g.add_argument("--right-topic", metavar="TOPIC", default=None, help="right image topic (stereo)")
    g.add_argument("--depth-topic", metavar="TOPIC", default=None, help="depth image topic (RGB-D)")
    g.add_argument("--ground-truth-topic", metavar="TOPIC", default=None,
                   help="PoseStamped, Odometry or TransformStamped topic of the left camera's poses")
    g.add_argument("--stamp-tolerance", metavar="SECONDS", type=float, default=None,
                   help=f"the most two images' stamps may differ to make one frame (default: "
                        f"{STEREO_TOLERANCE_S * 1e3:g} ms for a stereo pair, {RGBD_TOLERANCE_S * 1e3:g} ms for colour "
                        f"and depth); messages without a partner are left out and counted")


def bag_options(args: argparse.Namespace) -> dict[str, Any]:
    """The bag options given on the command line, as :func:`gtvo.datasets.open_sequence` keywords."""
    keys = ("calib", "left_topic", "right_topic", "depth_topic", "ground_truth_topic", "stamp_tolerance")
    options = {k: getattr(args, k) for k in keys if getattr(args, k, None) is not None}
    tolerance = options.get("stamp_tolerance")
    if tolerance is not None and not (math.isfinite(tolerance) and tolerance > 0):
        raise InputError(f"--stamp-tolerance must be a positive number of seconds, got {tolerance:g}")
    return options
