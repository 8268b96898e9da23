"""Options of ROS bag input shared by ``gtvo run`` and ``gtvo info``."""

from __future__ import annotations

import argparse
from typing import Any


def add_bag_options(p: argparse.ArgumentParser) -> None:
    """``--calib``, ``--left-topic``, ``--right-topic``, ``--depth-topic``, ``--ground-truth-topic``."""
    g = p.add_argument_group("ROS bags (.bag file or ROS2 bag folder)")
    g.add_argument("--calib", metavar="FILE", default=None,
                   help="calibration instead of the bag's CameraInfo: KITTI calib.txt, EuRoC cam0 sensor.yaml, "
                        "or a YAML of left:/right: camera_info blocks (docs/datasets.md)")
    g.add_argument("--left-topic", metavar="TOPIC", default=None, help="left (or RGB-D colour) image topic")
    g.add_argument("--right-topic", metavar="TOPIC", default=None, help="right image topic (stereo)")
    g.add_argument("--depth-topic", metavar="TOPIC", default=None, help="depth image topic (RGB-D)")
    g.add_argument("--ground-truth-topic", metavar="TOPIC", default=None,
                   help="PoseStamped, Odometry or TransformStamped topic of the left camera's poses")


def bag_options(args: argparse.Namespace) -> dict[str, Any]:
    """The bag options given on the command line, as :func:`gtvo.datasets.open_sequence` keywords."""
    keys = ("calib", "left_topic", "right_topic", "depth_topic", "ground_truth_topic")
    return {k: getattr(args, k) for k in keys if getattr(args, k, None) is not None}
