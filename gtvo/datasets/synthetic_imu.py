"""The IMU a synthetic camera would carry (docs/imu.md, "Synthetic logs"; ``gtvo synthetic --imu``).

Along a smooth synthetic motion (:func:`gtvo.datasets.synthetic.synthetic_poses_at`) the IMU sits at
``T_cam_imu`` on the left camera; its true pose is ``T_world_imu(t) = T_world_cam(t) T_cam_imu``.
At each reading time it measures

* the angular rate ``omega = log(R(t - h)^T R(t + h)) / 2h`` of its axes (body frame, rad/s), and
* the specific force ``f = R(t)^T (a(t) - g)`` (m/s^2) with ``a = (p(t + h) - 2 p(t) + p(t - h)) / h^2``
  its acceleration in the world and ``g`` gravity in the world (the synthetic world is the first
  camera's frame, y down: ``g = (0, +9.80665, 0)``; at rest the accelerometer reads 9.81 m/s^2 up),

by central differences with ``h = 1 ms`` on the exact curve (errors about 1e-7 in both), plus the
biases and the noise of :class:`ImuSimulation`: ``omega_m = omega + b_g + n_g``,
``f_m = f + b_a + n_a``, ``n ~ N(0, density^2 / dt)`` per reading and the biases walking by
``N(0, random_walk^2 dt)`` per reading from their initial values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gtvo.core.lie import so3_log
from gtvo.datasets.imu import DEFAULT_NOISE, GRAVITY_M_S2, ImuMeasurements, ImuNoise
from gtvo.errors import InputError, show

FloatArray = NDArray[np.float64]

#: ``T_cam_imu`` of the synthetic IMU: its axes x forward, y left, z up (a robot body's, REP 103) in
#: the camera's (x right, y down, z forward), 5 cm right of the left camera, 2 cm below, 3 cm behind.
SYNTHETIC_T_CAM_IMU: FloatArray = np.array([[0.0, -1.0, 0.0, 0.05],
                                            [0.0, 0.0, -1.0, 0.02],
                                            [1.0, 0.0, 0.0, -0.03],
                                            [0.0, 0.0, 0.0, 1.0]])
#: Gravity in the synthetic world (the first camera's frame, y down), m/s^2.
SYNTHETIC_GRAVITY: FloatArray = np.array([0.0, GRAVITY_M_S2, 0.0])
#: The central-difference step of the simulation (s).
DIFFERENCE_STEP_S = 1e-3


@dataclass(frozen=True)
class ImuSimulation:
    """What the synthetic IMU logs.

    Attributes:
        rate_hz: readings per second.
        noise: the white noise densities and bias random walks of the readings (and of the written
            ``sensor.yaml``).
        gyro_bias: the gyro's bias at the start (rad/s, IMU axes).
        accel_bias: the accelerometer's bias at the start (m/s^2, IMU axes).
        noisy: False: readings without white noise and without bias walk (the biases stay at their
            initial values): the exact motion, to test integration.
        seed: the noise's seed.
    """

    rate_hz: float = 200.0
    noise: ImuNoise = DEFAULT_NOISE
    gyro_bias: tuple[float, float, float] = (0.01, -0.02, 0.015)
    accel_bias: tuple[float, float, float] = (0.05, -0.03, 0.08)
    noisy: bool = True
    seed: int = 0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.rate_hz) and 20.0 <= self.rate_hz <= 10000.0):
            raise InputError(f"the IMU's rate must be 20..10000 Hz, got {show(self.rate_hz)}")
        for name in ("gyro_bias", "accel_bias"):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != (3,) or not np.all(np.isfinite(value)):
                raise InputError(f"{name} must be 3 finite numbers, got {show(getattr(self, name))}")


def true_imu_motion(times: FloatArray, poses_at, T_cam_imu: FloatArray = SYNTHETIC_T_CAM_IMU,
                    gravity: FloatArray = SYNTHETIC_GRAVITY) -> tuple[FloatArray, FloatArray]:
    """``(omega (M, 3), f (M, 3))``: the exact angular rate and specific force of the IMU (module
    doc) at ``times``, along ``poses_at(times) -> T_world_cam (M, 4, 4)``."""
    h = DIFFERENCE_STEP_S
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    T = [poses_at(t + d) @ T_cam_imu for d in (-h, 0.0, h)]
    R_minus, R_0, R_plus = (x[:, :3, :3] for x in T)
    omega = so3_log(np.einsum("nji,njk->nik", R_minus, R_plus)) / (2 * h)
    accel_world = (T[2][:, :3, 3] - 2 * T[1][:, :3, 3] + T[0][:, :3, 3]) / (h * h)
    f = np.einsum("nji,nj->ni", R_0, accel_world - gravity)
    return omega, f


def simulate_imu(t0: float, t1: float, poses_at, simulation: ImuSimulation = ImuSimulation(),
                 T_cam_imu: FloatArray = SYNTHETIC_T_CAM_IMU, source: str = "synthetic IMU") -> ImuMeasurements:
    """The readings of the synthetic IMU from ``t0`` to ``t1`` (module doc) along
    ``poses_at(times) -> T_world_cam``, with ``T_cam_imu`` as their extrinsic."""
    sim = simulation
    dt = 1.0 / sim.rate_hz
    times = t0 + np.arange(int(np.floor((t1 - t0) / dt + 1e-9)) + 1) * dt
    omega, f = true_imu_motion(times, poses_at, T_cam_imu)
    n = times.size
    gyro_bias = np.tile(np.asarray(sim.gyro_bias, dtype=np.float64), (n, 1))
    accel_bias = np.tile(np.asarray(sim.accel_bias, dtype=np.float64), (n, 1))
    if sim.noisy:
        rng = np.random.default_rng(int(sim.seed))
        walk = rng.normal(size=(2, n, 3)) * np.sqrt(dt)
        gyro_bias += np.cumsum(np.vstack([np.zeros((1, 3)), walk[0, 1:]]), axis=0) * sim.noise.gyro_random_walk
        accel_bias += np.cumsum(np.vstack([np.zeros((1, 3)), walk[1, 1:]]), axis=0) * sim.noise.accel_random_walk
        white = rng.normal(size=(2, n, 3)) / np.sqrt(dt)
        omega = omega + white[0] * sim.noise.gyro_noise_density
        f = f + white[1] * sim.noise.accel_noise_density
    return ImuMeasurements(times, omega + gyro_bias, f + accel_bias, sim.noise, T_cam_imu, source,
                           extrinsic_source="synthetic")
