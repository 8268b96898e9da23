"""The IMU readings beside a sequence (gtvo.datasets.imu): checks that refuse in one line, intervals."""

from __future__ import annotations

import numpy as np
import pytest

from gtvo.datasets.imu import DEFAULT_NOISE, ImuMeasurements, check_imu_clock, check_imu_readings
from gtvo.errors import InputError


def _readings(n=100, rate=200.0):
    t = np.arange(n) / rate
    gyro = np.column_stack([0.1 * np.sin(t), np.zeros(n), np.full(n, 0.2)])
    accel = np.tile([0.0, 0.0, 9.81], (n, 1))
    return t, gyro, accel


@pytest.mark.parametrize("edit, message", [
    (lambda t, w, a: a.__setitem__((5, 1), np.nan), "row 5: not a finite IMU reading"),
    (lambda t, w, a: t.__setitem__(7, t[6]), "row 7: time .* is not after"),
    (lambda t, w, a: t.__setitem__(slice(40, None), t[40:] + 0.2), "row 40: a gap of 0.205 s"),
    (lambda t, w, a: w.__setitem__((9, 2), 90.0), "row 9: an angular rate of 90 rad/s.*degrees per second"),
    (lambda t, w, a: a.__setitem__((3, 2), 1000.0), "row 3: a specific force of 1000 m/s\\^2.*milli-g"),
    (lambda t, w, a: a.__setitem__(slice(None), a / 9.81), "row 0: the accelerometer's median reading is 1 m/s\\^2.*in g"),
])
def test_bad_readings_are_refused_naming_the_row(edit, message):
    t, w, a = _readings()
    edit(t, w, a)
    with pytest.raises(InputError, match=message):
        check_imu_readings(t, w, a, "imu.csv")


def test_a_slow_imu_is_refused_for_preintegration():
    t, w, a = _readings(rate=20.0)
    with pytest.raises(InputError, match="rate is 20 Hz, below the 50 Hz"):
        check_imu_readings(t, w, a, "imu.csv")
    check_imu_readings(t, w, a, "imu.csv", min_rate=10.0, max_gap=1.0)


def test_another_clock_is_refused():
    t, w, a = _readings()
    imu = ImuMeasurements(t, w, a, DEFAULT_NOISE, np.eye(4), "imu.csv")
    check_imu_clock(imu, [0.1, 0.2, 0.3])
    with pytest.raises(InputError, match="another clock"):
        check_imu_clock(imu, [1e9, 1e9 + 0.1])


def test_interval_sums_to_its_span_and_takes_the_midpoint_of_the_readings():
    t, w, a = _readings()
    imu = ImuMeasurements(t, w, a, DEFAULT_NOISE, np.eye(4), "imu.csv")
    dt, gyro, accel = imu.interval(0.0123, 0.2)
    assert dt.sum() == pytest.approx(0.2 - 0.0123, abs=1e-15)
    assert np.all(dt > 0) and len(dt) == 38
    np.testing.assert_allclose(gyro[1], 0.5 * (w[3] + w[4]))  # the piece between readings 3 and 4
    np.testing.assert_allclose(accel, np.tile([0, 0, 9.81], (len(dt), 1)))
    dt, _, _ = imu.interval(-1.0, 0.001)  # before the first reading: it holds
    assert dt.sum() == pytest.approx(1.001)


def test_extrinsic_must_be_rigid():
    t, w, a = _readings()
    with pytest.raises(InputError, match="T_cam_imu is not a rigid transform"):
        ImuMeasurements(t, w, a, DEFAULT_NOISE, 2 * np.eye(4), "imu.csv")
