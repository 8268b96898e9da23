"""``gtvo synthetic --out DIR``: write the synthetic stereo sequence in the KITTI odometry layout (or a
ROS bag with ``--bag``), with a ground robot's wheel odometry (``--wheel``) or an IMU (``--imu``) on request."""

from __future__ import annotations

import argparse

from gtvo.core.atomic import output_lock
from gtvo.commands._common import parse_floats
from gtvo.datasets.bag_writer import write_sequence_bag
from gtvo.datasets.imu import DEFAULT_NOISE, ImuNoise
from gtvo.datasets.synthetic import MAX_SIDE, MIN_SIDE, SMOOTH_MOTIONS, make_synthetic_sequence, write_sequence_kitti
from gtvo.datasets.synthetic_imu import ImuSimulation
from gtvo.datasets.synthetic_robot import SYNTHETIC_WHEEL_RADIUS, WheelSimulation
from gtvo.datasets.wheel import DEFAULT_NOMINAL_BASELINE
from gtvo.errors import InputError


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
    p.add_argument("--motion", choices=("forward", "loop", "turn", "ground", "swerve"), default="forward",
                   help="camera path: forward with wobbles (default), an elliptic loop, a car's right turn, a "
                        "ground robot's slalom (a level camera on a diff-drive base: docs/wheel_odometry.md), or "
                        "forward with fast turns (yaw +-30 deg every 4 s, up to 47 deg/s)")
    p.add_argument("--noise-sigma", type=float, default=0.0, help="Gaussian image noise in gray levels")
    p.add_argument("--exposure-change", action="store_true", help="apply the known per-frame affine brightness")
    p.add_argument("--seed", type=int, default=0, help="seed of textures, box layout and noise (default 0)")
    p.add_argument("--bag", action="store_true",
                   help="write a ROS bag at --out instead (a .bag file: ROS1; else a ROS2 folder): images, camera_info, "
                        "/ground_truth and, with --wheel, /odom, /joint_states and /tf_static")
    w = p.add_argument_group("wheel odometry of the robot (docs/wheel_odometry.md)")
    w.add_argument("--wheel", choices=("arcs", "pose"), default=None,
                   help="also write wheel odometry: cumulative wheel arcs or the robot's planar pose "
                        "(wheel_odometry.csv and wheel.yaml beside the images)")
    w.add_argument("--wheel-calibration", metavar="K_L,K_R,K_B|X11,...,X33", default="1,1,1",
                   help="the true calibration that the readings need: diff-drive wheel and track-width scales, or "
                        "the 9 entries of the linear model's X row-major (default 1,1,1: none)")
    w.add_argument("--wheel-noise", type=float, default=0.0, metavar="SIGMA",
                   help="standard deviation of each reading's increment (arcs: m per wheel; pose: m and rad)")
    w.add_argument("--wheel-baseline", type=float, default=DEFAULT_NOMINAL_BASELINE, metavar="M",
                   help=f"the robot's nominal track width (m, default {DEFAULT_NOMINAL_BASELINE})")
    m = p.add_argument_group("IMU on the camera (docs/imu.md)")
    m.add_argument("--imu", action="store_true",
                   help="also write the IMU's readings along the exact motion (imu0/data.csv and imu0/sensor.yaml "
                        "beside the images; gtvo run reads them by itself); smooth motions only (forward, loop, swerve)")
    m.add_argument("--imu-rate", type=float, default=ImuSimulation.rate_hz, metavar="HZ",
                   help=f"readings per second (default {ImuSimulation.rate_hz:g})")
    m.add_argument("--imu-noise", metavar="GYRO_ND,ACCEL_ND,GYRO_RW,ACCEL_RW", default=None,
                   help="noise densities (rad/s/sqrt(Hz), m/s^2/sqrt(Hz)) and bias random walks (rad/s^2/sqrt(Hz), "
                        "m/s^3/sqrt(Hz)); default EuRoC's ADIS16448")
    m.add_argument("--imu-bias", metavar="GX,GY,GZ,AX,AY,AZ", default=None,
                   help="the biases at the start (rad/s, m/s^2, IMU axes); default "
                        + ",".join(f"{v:g}" for v in (*ImuSimulation.gyro_bias, *ImuSimulation.accel_bias)))
    m.add_argument("--imu-exact", action="store_true",
                   help="readings without white noise and without bias walk (the biases stay at --imu-bias)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Render and write the sequence; print where it went."""
    if args.frames < 1:
        raise InputError(f"--frames must be >= 1, got {args.frames}")
    if not (MIN_SIDE <= args.width <= MAX_SIDE and MIN_SIDE <= args.height <= MAX_SIDE):
        raise InputError(f"--width and --height must be between {MIN_SIDE} and {MAX_SIDE}, got {args.width}x{args.height}")
    wheels = None
    if args.wheel is None:
        given = [flag for flag, value, default in (("--wheel-calibration", args.wheel_calibration, "1,1,1"),
                                                   ("--wheel-noise", args.wheel_noise, 0.0),
                                                   ("--wheel-baseline", args.wheel_baseline, DEFAULT_NOMINAL_BASELINE))
                 if value != default]
        if given:
            raise InputError(f"{', '.join(given)} describe the wheel odometry: add --wheel arcs or --wheel pose")
    else:
        calibration = args.wheel_calibration.replace(",", " ").split()
        if len(calibration) not in (3, 9):
            raise InputError(f"--wheel-calibration must be 3 numbers (k_L,k_R,k_b) or 9 (X row-major), "
                             f"got {args.wheel_calibration!r}")
        cal = parse_floats(args.wheel_calibration, len(calibration), "--wheel-calibration")
        wheels = WheelSimulation(kind=args.wheel, calibration=tuple(cal), noise=args.wheel_noise, seed=args.seed,
                                 nominal_baseline=args.wheel_baseline)
    imu = _imu_simulation(args)
    seq = make_synthetic_sequence(n_frames=args.frames, width=args.width, height=args.height, motion=args.motion,
                                  noise_sigma=args.noise_sigma, exposure_change=args.exposure_change, seed=args.seed,
                                  wheels=wheels, imu=imu)
    with output_lock(args.out):  # one writer at a time, as gtvo run's
        if args.bag:
            out = write_sequence_bag(seq, args.out, wheel_radius=SYNTHETIC_WHEEL_RADIUS, progress=not args.no_progress)
        else:
            out = write_sequence_kitti(seq, args.out, progress=not args.no_progress)
    with_wheels = "" if wheels is None else f" with wheel odometry ({wheels.kind})"
    if imu is not None:
        with_wheels += f" with an IMU ({imu.rate_hz:g} Hz)"
    print(f"wrote {len(seq)} stereo pairs ({seq.pinhole.width}x{seq.pinhole.height}, {args.motion}){with_wheels} "
          f"to {out}")
    return 0


def _imu_simulation(args: argparse.Namespace) -> ImuSimulation | None:
    """The IMU of ``--imu`` and its options (refused without ``--imu``, or on a motion that is not smooth)."""
    if not args.imu:
        given = [flag for flag, value in (("--imu-rate", args.imu_rate != ImuSimulation.rate_hz),
                                          ("--imu-noise", args.imu_noise is not None),
                                          ("--imu-bias", args.imu_bias is not None), ("--imu-exact", args.imu_exact))
                 if value]
        if given:
            raise InputError(f"{', '.join(given)} describe the IMU: add --imu")
        return None
    if args.motion not in SMOOTH_MOTIONS:
        raise InputError(f"--imu needs a smooth --motion ({', '.join(SMOOTH_MOTIONS)}), got {args.motion}")
    noise = DEFAULT_NOISE
    if args.imu_noise is not None:
        noise = ImuNoise(*parse_floats(args.imu_noise, 4, "--imu-noise"), source="gtvo synthetic --imu-noise")
    bias = (*ImuSimulation.gyro_bias, *ImuSimulation.accel_bias)
    if args.imu_bias is not None:
        bias = tuple(parse_floats(args.imu_bias, 6, "--imu-bias"))
    return ImuSimulation(rate_hz=args.imu_rate, noise=noise, gyro_bias=bias[:3], accel_bias=bias[3:],  # type: ignore[arg-type]
                         noisy=not args.imu_exact, seed=args.seed)
