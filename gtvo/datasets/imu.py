"""An IMU beside a sequence: its readings, noise model and pose on the camera (docs/imu.md).

An :class:`ImuMeasurements` holds what an inertial measurement unit logged, in the sequence's
clock: the angular rate ``gyro`` (rad/s) and the specific force ``accel`` (m/s^2, gravity included:
an IMU at rest reads about 9.81 m/s^2 upwards) in the IMU's own axes, the continuous-time noise
densities and bias random walks of the two sensors (:class:`ImuNoise`), and ``T_cam_imu``, the IMU's
pose in the left (rectified) camera's frame. ``time_shift`` is what was subtracted from the
logged times to put them in the camera's clock (Kalibr's ``timeshift_cam_imu``, defined by
``t_imu = t_cam + shift``: so ``t_cam = t_imu - time_shift``).

:func:`check_imu_readings` refuses, in one line naming the source and the row, what cannot be an
IMU log in SI units: a non-finite reading, times that do not increase, a gap longer than
``max_gap``, a median rate below ``min_rate`` (preintegration between keyframes needs several
readings per frame), a gyro faster than :data:`MAX_GYRO_RAD_S` (degrees per second?), a specific
force beyond :data:`MAX_ACCEL_M_S2` (milli-g?) or an accelerometer whose median reading is far
below gravity (g instead of m/s^2?). :func:`check_imu_clock` refuses an IMU whose times do not
overlap the images' (another clock, nanoseconds for seconds).

Pure numpy (the shape, finiteness, order and gap checks are the wheel readings' own:
:func:`gtvo.datasets.wheel.check_timed_readings`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.config.sections.imu import MAX_GAP_S, MIN_RATE_HZ
from gtvo.datasets.wheel import check_gaps, check_timed_readings, reading_error
from gtvo.errors import InputError, show

FloatArray = NDArray[np.float64]

#: Columns of a plain IMU CSV after ``time`` (rad/s, then m/s^2).
IMU_COLUMNS: tuple[str, ...] = ("wx", "wy", "wz", "ax", "ay", "az")
#: The fastest angular rate accepted (rad/s): 2000 deg/s, the largest range of common MEMS gyros.
#: Faster readings are degrees per second.
MAX_GYRO_RAD_S = 35.0
#: The largest specific force accepted (m/s^2, 16 g); larger readings are in milli-g or another unit.
MAX_ACCEL_M_S2 = 16 * 9.81
#: The smallest median specific force accepted (m/s^2): a log of a vehicle on the ground or in
#: flight reads about gravity on average; an accelerometer in g reads about 1.
MIN_MEDIAN_ACCEL_M_S2 = 4.0
#: Standard gravity (m/s^2).
GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class ImuNoise:
    """The IMU's continuous-time noise model (Kalibr's and EuRoC's names and units).

    Attributes:
        gyro_noise_density: the gyro's white noise (rad/s/sqrt(Hz)).
        accel_noise_density: the accelerometer's white noise (m/s^2/sqrt(Hz)).
        gyro_random_walk: the gyro bias's random walk (rad/s^2/sqrt(Hz)).
        accel_random_walk: the accelerometer bias's random walk (m/s^3/sqrt(Hz)).
        source: where the numbers came from (a file, the config, or "default").
    """

    gyro_noise_density: float
    accel_noise_density: float
    gyro_random_walk: float
    accel_random_walk: float
    source: str = "default"

    def __post_init__(self) -> None:
        for name in ("gyro_noise_density", "accel_noise_density", "gyro_random_walk", "accel_random_walk"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise InputError(f"the IMU's {name} must be a positive number, got {show(value)}", self.source)


#: The noise of the ADIS16448 on the EuRoC MAV (its ``imu0/sensor.yaml``): used when neither the log
#: nor the config's ``imu:`` section gives one.
DEFAULT_NOISE = ImuNoise(1.6968e-4, 2.0e-3, 1.9393e-5, 3.0e-3, "default (EuRoC's ADIS16448)")


def check_imu_readings(times: ArrayLike, gyro: ArrayLike, accel: ArrayLike, source: str,
                       rows: ArrayLike | None = None, row_name: str = "row", min_rate: float | None = MIN_RATE_HZ,
                       max_gap: float | None = MAX_GAP_S) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(times, gyro, accel)`` as float arrays, checked (module doc).

    Raises:
        InputError: one line naming ``source`` and the first bad reading
            (:func:`gtvo.datasets.wheel.reading_error`; ``rows``: the file's line numbers or a bag's
            message numbers, default the index).
    """
    checked = check_timed_readings(times, [(gyro, IMU_COLUMNS[:3]), (accel, IMU_COLUMNS[3:])], "an IMU",
                                   "IMU reading", source, rows, row_name)
    t, (w, a) = checked.times, checked.values
    refuse = checked.refuse
    step = np.diff(t)
    if min_rate is not None:
        rate = 1.0 / float(np.median(step))
        if rate < min_rate:
            raise refuse(1, f"the IMU's rate is {rate:.4g} Hz, below the {min_rate:g} Hz that preintegration between "
                            "keyframes needs (imu.min_rate; times in another unit?)")
    if max_gap is not None:  # after the rate: a slow log has long gaps too, and its rate says why
        check_gaps(checked, max_gap, "IMU reading", "imu.max_gap")
    rate_norm = np.linalg.norm(w, axis=1)
    if np.any(rate_norm > MAX_GYRO_RAD_S):
        i = int(np.flatnonzero(rate_norm > MAX_GYRO_RAD_S)[0])
        raise refuse(i, f"an angular rate of {rate_norm[i]:.4g} rad/s, more than {MAX_GYRO_RAD_S:g} rad/s "
                        "(2000 deg/s): degrees per second? the gyro must read rad/s")
    norm = np.linalg.norm(a, axis=1)
    if np.any(norm > MAX_ACCEL_M_S2):
        i = int(np.flatnonzero(norm > MAX_ACCEL_M_S2)[0])
        raise refuse(i, f"a specific force of {norm[i]:.4g} m/s^2, more than 16 g: milli-g or another unit? "
                        "the accelerometer must read m/s^2")
    if float(np.median(norm)) < MIN_MEDIAN_ACCEL_M_S2:
        i = int(np.flatnonzero(norm < MIN_MEDIAN_ACCEL_M_S2)[0])
        raise refuse(i, f"the accelerometer's median reading is {np.median(norm):.4g} m/s^2, far below gravity "
                        f"({GRAVITY_M_S2} m/s^2): in g? the accelerometer must read m/s^2, gravity included")
    return t, w, a


def check_imu_clock(imu: "ImuMeasurements", frame_times: ArrayLike, where: str | None = None) -> None:
    """Refuse an IMU whose readings do not overlap the frames' times (another clock, another unit).

    Raises:
        InputError: one line naming the IMU's source and its first reading.
    """
    f = np.asarray(frame_times, dtype=np.float64).reshape(-1)
    overlap = min(imu.times[-1], f[-1]) - max(imu.times[0], f[0])
    span = max(f[-1] - f[0], 0.0)
    if overlap < 0 or (span > 0 and overlap < 0.5 * min(span, imu.times[-1] - imu.times[0])):
        raise reading_error(f"the IMU's times {imu.times[0]:.9g}..{imu.times[-1]:.9g} s hardly overlap the images' "
                            f"{f[0]:.9g}..{f[-1]:.9g} s: another clock (or time unit)? set imu.time_shift or "
                            "give the IMU log in the images' clock", where or imu.source, "reading", 0)


@dataclass(frozen=True, eq=False)
class ImuMeasurements:
    """An IMU's readings in the sequence's clock, its noise model and its pose on the camera.

    Attributes:
        times: (N,) seconds in the images' clock (strictly increasing; ``time_shift`` applied).
        gyro: (N, 3) angular rate of the IMU in its axes (rad/s).
        accel: (N, 3) specific force in the IMU's axes (m/s^2, gravity included).
        noise: the noise densities and bias random walks.
        T_cam_imu: (4, 4) the IMU's pose in the left (rectified) camera's frame.
        source: the file path or ``"bag:/topic"``, for messages.
        time_shift: seconds subtracted from the logged times (``t_images = t_logged - time_shift``).
        extrinsic_source: where ``T_cam_imu`` came from (a file, a bag's ``/tf_static``, the config).
    """

    times: FloatArray
    gyro: FloatArray
    accel: FloatArray
    noise: ImuNoise
    T_cam_imu: FloatArray
    source: str
    time_shift: float = 0.0
    extrinsic_source: str = ""
    _checked: bool = field(default=False, repr=False)

    def __post_init__(self) -> None:
        if not self._checked:
            t, w, a = check_imu_readings(self.times, self.gyro, self.accel, self.source, row_name="reading",
                                         min_rate=None, max_gap=None)
            object.__setattr__(self, "times", t)
            object.__setattr__(self, "gyro", w)
            object.__setattr__(self, "accel", a)
        T = np.asarray(self.T_cam_imu, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"T_cam_imu must be a finite 4x4 transform, got shape {T.shape}", self.source)
        R = T[:3, :3]
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0 or np.abs(T[3] - [0, 0, 0, 1]).max() > 0:
            raise InputError("T_cam_imu is not a rigid transform (its rotation block is not a rotation, or its "
                             "bottom row is not 0 0 0 1)", self.extrinsic_source or self.source)
        object.__setattr__(self, "T_cam_imu", T)

    def __len__(self) -> int:
        return int(self.times.size)

    @property
    def rate_hz(self) -> float:
        """The median reading rate (Hz)."""
        return float(1.0 / np.median(np.diff(self.times)))

    def covers(self, t0: float, t1: float) -> bool:
        """True when the readings span ``[t0, t1]``."""
        return bool(self.times[0] <= t0 <= t1 <= self.times[-1])

    def interval(self, t0: float, t1: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The readings between ``t0 < t1`` as piecewise-constant samples for preintegration:
        ``(dt (M,), gyro (M, 3), accel (M, 3))`` over the pieces cut at ``t0``, every reading time
        inside and ``t1`` (the sum of ``dt`` exactly ``t1 - t0``), each piece's value the readings
        linearly interpolated at its midpoint (between two readings their mean: the midpoint rule,
        second-order accurate, VINS-Fusion's). Outside the readings the nearest reading holds.
        """
        if not t1 > t0:
            raise InputError(f"an IMU interval needs t1 > t0, got {t0:.9g}..{t1:.9g}", self.source)
        inside = self.times[(self.times > t0) & (self.times < t1)]
        edges = np.concatenate([[t0], inside, [t1]])
        mid = 0.5 * (edges[:-1] + edges[1:])
        gyro = np.stack([np.interp(mid, self.times, self.gyro[:, k]) for k in range(3)], axis=1)
        accel = np.stack([np.interp(mid, self.times, self.accel[:, k]) for k in range(3)], axis=1)
        dt = np.diff(edges)
        keep = dt > 0
        return dt[keep], gyro[keep], accel[keep]

    def window(self, t0: float, t1: float) -> "ImuMeasurements":
        """The readings with times in ``[t0, t1]`` (the same noise and extrinsic)."""
        m = (self.times >= t0) & (self.times <= t1)
        return ImuMeasurements(self.times[m], self.gyro[m], self.accel[m], self.noise, self.T_cam_imu, self.source,
                               self.time_shift, self.extrinsic_source)
