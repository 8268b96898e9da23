"""``gtvo run``: offline odometry of a logged sequence (any layout of :data:`gtvo.datasets.FORMATS`)."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from gtvo.commands._bag import add_bag_options, bag_options
from gtvo.commands._common import add_odometry_options, describe_solvers, odometry_config, parse_floats, print_report
from gtvo.commands._viewer import add_viewer_options, viewer_observers
from gtvo.core.interrupt import outputs_in_place
from gtvo.datasets import FORMATS
from gtvo.errors import InputError


#: The wheel odometry's flags: ``open_sequence``'s ``wheel_odometry`` and ``wheel_topic``.
WHEEL_FLAGS: tuple[tuple[str, str, str], ...] = (
    ("--wheel-odometry", "FILE", "a wheel odometry CSV (time,x,y,theta or time,left,right) instead of the sequence "
                                 "folder's wheel_odometry.csv or the bag's wheel topic"),
    ("--wheel-topic", "TOPIC", "the bag's wheel odometry topic (nav_msgs/Odometry, geometry_msgs/TwistStamped, "
                               "sensor_msgs/JointState; default: the only one; 'none': no wheel odometry)"),
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run", help="odometry of a logged sequence; writes trajectory, report, plots, points",
        description="Track every frame of a KITTI (odometry or raw) / EuRoC / TUM RGB-D sequence or a ROS bag "
                    "and write DIR/trajectory.tum, DIR/report.json (with ATE, RPE and drift when ground truth "
                    "exists), DIR/trajectory.png and DIR/points.ply.")
    p.add_argument("sequence", metavar="SEQUENCE_DIR", help="the sequence folder, or a ROS bag (.bag, ROS2 folder)")
    p.add_argument("--format", choices=("auto",) + FORMATS, default="auto",
                   help="dataset layout (default: auto-detect)")
    p.add_argument("--out", metavar="DIR", default=None, help="output folder (default gtvo_out/<name>)")
    p.add_argument("--max-frames", type=int, metavar="N", default=None, help="use only the first N frames")
    p.add_argument("--frame-step", type=int, metavar="K", default=1,
                   help="use every K-th frame (after --max-frames): the log at 1/K of its frame rate")
    p.add_argument("--camera", metavar="FX,FY,CX,CY", default=None, help="intrinsics for TUM folders")
    p.add_argument("--ground-truth", metavar="FILE", default=None,
                   help="ground truth to use instead of the folder's (KITTI raw: an oxts folder)")
    p.add_argument("--strict", action="store_true", help="stop at an unreadable frame instead of skipping it")
    p.add_argument("--loop-closure", action="store_true",
                   help="detect loops among the keyframes, optimise the keyframe pose graph robustly (GNC), "
                        "re-measure every tracked frame against the final keyframes and write "
                        "DIR/trajectory_loop_closed.tum as a second output (the map on the loop-closed keyframes)")
    p.add_argument("--no-covariances", action="store_true",
                   help="do not compute the keyframes' pose covariances (no DIR/covariances.npz, no ellipses)")
    _on_off(p, "rig-calibration",
            "estimate the stereo rig's rectification error (the right image's offset, px) in the "
            "window (config key window.rig_calibration; on by default: docs/window.md)",
            "the rectified model throughout (overrides window.rig_calibration of a --config file)")
    _on_off(p, "refine",
            "after the window pass (and loop closing), optimise one graph over every keyframe and "
            "re-place the other frames against them (config key refine.enabled; docs/refinement.md)",
            "no whole-log refinement: the window's answer (overrides refine.enabled of a --config file)")
    wheel = p.add_argument_group("wheel odometry (docs/wheel_odometry.md)")
    for flag, metavar, text in WHEEL_FLAGS:
        wheel.add_argument(flag, metavar=metavar, default=None, help=text)
    imu = p.add_argument_group("IMU (docs/imu.md)")
    imu.add_argument("--imu", metavar="FILE", default=None,
                     help="an IMU CSV (time,wx,wy,wz,ax,ay,az in s, rad/s, m/s^2, or EuRoC's imu0/data.csv) instead "
                          "of the sequence folder's imu0/data.csv or the bag's sensor_msgs/Imu topic")
    imu.add_argument("--imu-topic", metavar="TOPIC", default=None,
                     help="the bag's IMU topic (sensor_msgs/Imu; default: the only one; 'none': no IMU)")
    imu.add_argument("--no-imu", action="store_true",
                     help="vision only on a log that has an IMU (config key imu.enabled)")
    _on_off(p, "parallel",
            "run the window in a worker process beside the front end (config key window.parallel: "
            "the second core; the same answer every run; docs/window.md)",
            "the window after the front end in one process, the sequential order (overrides "
            "window.parallel of a --config file)")
    add_odometry_options(p)
    add_bag_options(p)
    add_viewer_options(p)
    p.set_defaults(func=main)


def _on_off(p: argparse.ArgumentParser, name: str, on_help: str, off_help: str) -> None:
    """``--NAME`` and ``--no-NAME``, mutually exclusive (neither: the config's value)."""
    group = p.add_mutually_exclusive_group()
    group.add_argument(f"--{name}", action="store_true", help=on_help)
    group.add_argument(f"--no-{name}", action="store_true", help=off_help)


def main(args: argparse.Namespace) -> int:
    from gtvo.pipeline import run  # noqa: PLC0415

    for flag, value in (("--max-frames", args.max_frames), ("--frame-step", args.frame_step)):
        if value is not None and value < 1:
            raise InputError(f"{flag} must be >= 1, got {value}")
    options = bag_options(args)
    if args.camera is not None:
        options["camera"] = parse_floats(args.camera, 4, "--camera")
    if args.ground_truth is not None:
        options["ground_truth"] = args.ground_truth
    options.update({k: getattr(args, k) for k in ("wheel_odometry", "wheel_topic", "imu", "imu_topic")
                    if getattr(args, k) is not None})
    config = odometry_config(args)
    if args.no_imu:
        config = dataclasses.replace(config, imu=dataclasses.replace(config.imu, enabled=False))
    if args.no_covariances:
        config = dataclasses.replace(config, window=dataclasses.replace(config.window, covariances=False))
    if args.rig_calibration and config.mode != "window":
        raise InputError(f"--rig-calibration needs --mode window (got --mode {config.mode}): the rig's offset is "
                         f"estimated in the window")
    if args.rig_calibration or args.no_rig_calibration:
        config = dataclasses.replace(config, window=dataclasses.replace(config.window,
                                                                        rig_calibration=bool(args.rig_calibration)))
    if args.parallel or args.no_parallel:
        config = dataclasses.replace(config, window=dataclasses.replace(config.window, parallel=bool(args.parallel)))
    if args.refine and config.mode != "window":
        raise InputError(f"--refine needs --mode window (got --mode {config.mode}): it refines the window's keyframes")
    if args.refine or args.no_refine:
        config = dataclasses.replace(config, refine=dataclasses.replace(config.refine, enabled=bool(args.refine)))
    with viewer_observers(args) as observers:
        report = run(args.sequence, out=args.out, config=config, format=args.format,
                     max_frames=args.max_frames, progress=not args.no_progress, strict=args.strict,
                     loop_closure=args.loop_closure, frame_step=args.frame_step, observers=observers, **options)
    outputs_in_place()  # the run has succeeded: a Ctrl-C while it prints its summary changes nothing
    print(f"gtvo run: {report['sequence']} ({describe_solvers(report)})", file=sys.stdout)
    print_report(report)
    return 0
