"""The ``imu:`` section of the tree: what an IMU's files do not say (its noise model, its pose on the
camera, its clock's offset), how its readings are checked, and whether it is used (docs/imu.md).
Used only when a sequence has an IMU. The readers (:func:`gtvo.datasets.imu_files.imu_read_options`)
and the window (:func:`gtvo.window.imu.imu_window_settings`) take their settings from it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gtvo.core.settings import SettingError, check_settings, setting

#: The lowest median reading rate (Hz) accepted (``imu.min_rate``): preintegration between keyframes
#: needs several readings per camera frame.
MIN_RATE_HZ = 50.0
#: The longest time between two readings (s) accepted (``imu.max_gap``).
MAX_GAP_S = 0.05
#: The span of readings and keyframes (s) the window's initialisation waits for (``imu.init_seconds``).
INIT_SECONDS = 1.0
#: The accelerometer bias prior's sigma (m/s^2) about zero (``imu.accel_bias_sigma``).
ACCEL_BIAS_SIGMA = 0.2
#: The gyro bias prior's sigma (rad/s) about the initialisation's estimate (``imu.gyro_bias_sigma``).
GYRO_BIAS_SIGMA = 0.05


@dataclass(frozen=True)
class ImuConfig:
    """An IMU beside the images: used when the log has one (docs/imu.md).

    Attributes:
        enabled: use the log's IMU; false runs vision only on a log that has one (gtvo run --no-imu).
        topic: the bag topic of the IMU (--imu-topic, a sensor_msgs/Imu); null: the bag's one IMU topic; none: no IMU from the bag.
        imu_in_camera: T_cam_imu, the IMU's pose in the left (rectified) camera's frame, as [x, y, z, qx, qy, qz, qw] (m; a unit quaternion), when no file gives it (a Kalibr camchain-imucam.yaml, an imu0/sensor.yaml, a bag's /tf_static); null: such a file is needed.
        time_shift: seconds subtracted from the IMU's times to put them in the images' clock (Kalibr's timeshift_cam_imu), when no camchain-imucam.yaml gives it.
        gyro_noise_density: the gyro's white noise (rad/s/sqrt(Hz)) when no file gives the noise model; null: EuRoC's ADIS16448 (all four together).
        accel_noise_density: the accelerometer's white noise (m/s^2/sqrt(Hz)), as gyro_noise_density.
        gyro_random_walk: the gyro bias's random walk (rad/s^2/sqrt(Hz)), as gyro_noise_density.
        accel_random_walk: the accelerometer bias's random walk (m/s^3/sqrt(Hz)), as gyro_noise_density.
        min_rate: the lowest median reading rate (Hz) accepted: preintegration between keyframes needs several readings per frame.
        max_gap: the longest time between two IMU readings (s) accepted; a longer gap is refused, naming the file and row.
        init_seconds: the span of readings and keyframes (s) the window's initialisation waits for (gravity, velocities, gyro bias; docs/imu.md).
        accel_bias_sigma: the prior sigma of the accelerometer bias (m/s^2) about zero.
        gyro_bias_sigma: the prior sigma of the gyro bias (rad/s) about the initialisation's estimate.
    """

    enabled: bool = True
    topic: str | None = None
    imu_in_camera: tuple[float, float, float, float, float, float, float] | None = setting(None, "[-1000, 1000]")
    time_shift: float = setting(0.0, "[-1000, 1000]")
    gyro_noise_density: float | None = setting(None, "(0, 10]")
    accel_noise_density: float | None = setting(None, "(0, 100]")
    gyro_random_walk: float | None = setting(None, "(0, 10]")
    accel_random_walk: float | None = setting(None, "(0, 100]")
    min_rate: float = setting(MIN_RATE_HZ, "(0, 100000]")
    max_gap: float = setting(MAX_GAP_S, "(0, 3600]")
    init_seconds: float = setting(INIT_SECONDS, "(0, 60]")
    accel_bias_sigma: float = setting(ACCEL_BIAS_SIGMA, "(0, 100]")
    gyro_bias_sigma: float = setting(GYRO_BIAS_SIGMA, "(0, 10]")

    def __post_init__(self) -> None:
        check_settings(self)
        if self.imu_in_camera is not None:
            norm = float(np.linalg.norm(self.imu_in_camera[3:]))
            if abs(norm - 1.0) > 1e-3:
                raise SettingError("imu_in_camera", f"qx, qy, qz, qw must be a unit quaternion, its norm is {norm:.6g}")
        noise = [self.gyro_noise_density, self.accel_noise_density, self.gyro_random_walk, self.accel_random_walk]
        if any(v is None for v in noise) and any(v is not None for v in noise):
            raise SettingError("gyro_noise_density", "the noise model is the four numbers gyro_noise_density, "
                                                     "accel_noise_density, gyro_random_walk, accel_random_walk together")
