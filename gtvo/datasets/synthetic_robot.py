"""The synthetic ground robot: a differential-drive base carrying the stereo camera through the
synthetic room in the plane, with turns both ways, and the wheel odometry it logs
(docs/wheel_odometry.md, "Synthetic ground robot"; docs/synthetic.md).

* :func:`ground_robot_trajectory`: camera poses ``T_world_cam`` (N, 4, 4) of a base that drives one
  exact arc per frame (constant speed, a yaw rate swinging left and right), the camera at
  :data:`SYNTHETIC_BASE_TO_CAMERA` on it; the world is the first camera's frame (y down), as every
  synthetic trajectory.
* :class:`WheelSimulation`: what the robot's wheels log (readings kind, calibration error, noise)
  and :func:`simulate_sequence_wheels`, its :class:`gtvo.datasets.wheel.WheelOdometry` along a
  sequence's ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gtvo.core.lie import invert_poses, pose_from_xyz_quaternion
from gtvo.datasets.wheel import DEFAULT_NOMINAL_BASELINE, WheelKind, WheelOdometry, simulate_wheel_odometry
from gtvo.errors import InputError, show

FloatArray = NDArray[np.float64]

#: ``T_base_cam`` of the synthetic robot as ``[x, y, z, qx, qy, qz, qw]``: a level, forward-looking
#: camera (``gtvo.config.sections.wheel.FORWARD_CAMERA_ON_BASE``'s rotation) 0.3 m ahead of the axle's
#: centre, 0.1 m right of it and 0.8 m above: in a turn the camera's path is not the base's.
SYNTHETIC_BASE_TO_CAMERA: tuple[float, ...] = (0.3, -0.1, 0.8, -0.5, 0.5, -0.5, 0.5)
#: The yaw rate's swing: its amplitude (deg per frame) and period (frames): a slalom whose heading
#: stays within about +-28 deg of the room's length, 17 deg/s at the turns' peak at 10 Hz.
GROUND_YAW_DEG_PER_FRAME = 1.7
GROUND_YAW_PERIOD_FRAMES = 100
#: The nominal wheel radius of the synthetic robot (m): its JointState wheel angles are arcs / radius.
SYNTHETIC_WHEEL_RADIUS = 0.1


def ground_robot_base_poses(n_frames: int, step_m: float) -> FloatArray:
    """(N, 3) planar base poses ``(x, y, theta)`` (REP 103, from the origin): one exact arc of length
    ``step_m`` per frame with yaw change ``GROUND_YAW_DEG_PER_FRAME * cos(2 pi k / period)`` deg."""
    from gtvo.wheel_calibration.diff_drive import diff_drive_motions_from_arcs  # noqa: PLC0415
    from gtvo.wheel_calibration.motions import integrate_motions  # noqa: PLC0415

    k = np.arange(int(n_frames) - 1)
    dtheta = np.deg2rad(GROUND_YAW_DEG_PER_FRAME) * np.cos(2 * np.pi * k / GROUND_YAW_PERIOD_FRAMES)
    b = 1.0  # any axle: the arc is fixed by its length and its yaw change
    steps = diff_drive_motions_from_arcs(step_m - b * dtheta / 2, step_m + b * dtheta / 2, b)
    return integrate_motions(steps)


def ground_robot_trajectory(n_frames: int, step_m: float = 0.15,
                            base_to_camera: tuple[float, ...] = SYNTHETIC_BASE_TO_CAMERA) -> FloatArray:
    """Camera poses ``T_world_cam`` (N, 4, 4) of the ground robot (module doc); frame 0 is the identity."""
    base = ground_robot_base_poses(n_frames, step_m)
    T_world_base = np.tile(np.eye(4), (len(base), 1, 1))
    c, s = np.cos(base[:, 2]), np.sin(base[:, 2])
    T_world_base[:, 0, 0], T_world_base[:, 0, 1], T_world_base[:, 1, 0], T_world_base[:, 1, 1] = c, -s, s, c
    T_world_base[:, 0, 3], T_world_base[:, 1, 3] = base[:, 0], base[:, 1]
    T_base_cam = pose_from_xyz_quaternion(base_to_camera)
    T_world_cam = T_world_base @ T_base_cam
    return invert_poses(T_world_cam[:1])[0] @ T_world_cam


@dataclass(frozen=True)
class WheelSimulation:
    """The wheel odometry a synthetic robot logs.

    Attributes:
        kind: ``"arcs"`` (cumulative wheel arcs, m) or ``"pose"`` (the robot's integrated planar pose).
        calibration: the true calibration a calibrated model recovers: ``(k_L, k_R, k_b)`` (diff-drive)
            or the 9 entries of the linear model's X, row-major (:func:`simulate_wheel_odometry`).
        noise: per-reading standard deviation of each increment (arcs: m per wheel; pose: m, m, rad).
        seed: the noise's seed.
        nominal_baseline: the track width the robot's own odometry uses, b0 (m).
        base_to_camera: ``T_base_cam`` as ``[x, y, z, qx, qy, qz, qw]``.
    """

    kind: WheelKind = "arcs"
    calibration: tuple[float, ...] = (1.0, 1.0, 1.0)
    noise: float = 0.0
    seed: int = 0
    nominal_baseline: float = DEFAULT_NOMINAL_BASELINE
    base_to_camera: tuple[float, ...] = SYNTHETIC_BASE_TO_CAMERA

    def __post_init__(self) -> None:
        if self.kind not in ("arcs", "pose"):
            raise InputError(f"wheel odometry kind must be 'arcs' or 'pose', got {show(self.kind)}")
        if len(self.calibration) not in (3, 9) or not np.all(np.isfinite(self.calibration)):
            raise InputError(f"wheel calibration must be k_L,k_R,k_b or the 9 entries of X, got "
                             f"{show(self.calibration)}")
        if len(self.calibration) == 3 and min(self.calibration) <= 0:
            raise InputError(f"wheel scales k_L, k_R, k_b must be positive, got {show(self.calibration)}")
        if len(self.calibration) == 9 and abs(np.linalg.det(np.reshape(self.calibration, (3, 3)))) < 1e-6:
            raise InputError(f"the linear model's X must be invertible, got {show(self.calibration)}")
        if not (np.isfinite(self.noise) and self.noise >= 0):
            raise InputError(f"wheel noise must be finite and >= 0, got {show(self.noise)}")
        if not (np.isfinite(self.nominal_baseline) and self.nominal_baseline > 0):
            raise InputError(f"nominal baseline must be a positive length (m), got {show(self.nominal_baseline)}")

    @property
    def T_base_cam(self) -> FloatArray:
        """``base_to_camera`` as a 4x4 transform."""
        return pose_from_xyz_quaternion(self.base_to_camera)

    @property
    def model(self) -> str:
        """The calibration model whose parameters ``calibration`` holds: ``"linear"`` (9 entries of X)
        or ``"diff_drive"`` (``k_L, k_R, k_b``): the ``wheel.model`` that recovers it."""
        return "linear" if len(self.calibration) == 9 else "diff_drive"



def simulate_sequence_wheels(times: FloatArray, T_world_cam: FloatArray, wheels: WheelSimulation,
                             source: str = "synthetic") -> WheelOdometry:
    """The wheel odometry ``wheels`` describes along the camera poses ``T_world_cam`` at ``times``."""
    cal = np.asarray(wheels.calibration, dtype=np.float64)
    odo = simulate_wheel_odometry(times, T_world_cam, wheels.T_base_cam, wheels.kind,
                                  cal.reshape(3, 3) if cal.size == 9 else cal, wheels.noise, wheels.seed,
                                  nominal_baseline=wheels.nominal_baseline, source=source)
    return WheelOdometry(odo.times, odo.kind, odo.values, odo.source, odo.nominal_baseline, wheels.T_base_cam)


def wheel_config_yaml(odometry: WheelOdometry, model: str = "diff_drive") -> str:
    """The config file's ``wheel:`` section that reads ``odometry`` as written beside a synthetic
    sequence: the calibration ``model`` to estimate (:attr:`WheelSimulation.model`), its
    base-to-camera transform and nominal baseline (``gtvo run --config wheel.yaml``)."""
    from gtvo.core.lie import rotations_to_quaternions  # noqa: PLC0415

    T = odometry.base_to_camera if odometry.base_to_camera is not None else pose_from_xyz_quaternion(SYNTHETIC_BASE_TO_CAMERA)
    vector = [*T[:3, 3].tolist(), *rotations_to_quaternions(T[:3, :3])[0].tolist()]
    return ("# the wheel odometry of a synthetic ground robot (gtvo synthetic): gtvo run --config wheel.yaml\n"
            f"wheel:\n  model: {model}\n  base_to_camera: [{', '.join(f'{v:.12g}' for v in vector)}]\n"
            f"  nominal_baseline: {odometry.nominal_baseline!r}\n  wheel_radius: {SYNTHETIC_WHEEL_RADIUS!r}\n")
