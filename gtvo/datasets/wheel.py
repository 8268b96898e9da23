"""Wheel odometry beside a sequence: the raw planar readings a ground robot logs (docs/wheel_odometry.md).

A :class:`WheelOdometry` holds the readings as the robot logged them, in the sequence's clock:

* ``kind="pose"``: the base's planar pose ``(x, y, theta)`` in its odometry frame (REP 103 / 105:
  x forward, y left, theta counter-clockwise, metres and radians; theta unwrapped);
* ``kind="arcs"``: the cumulative left and right wheel arc lengths (metres; ticks already scaled).

:meth:`WheelOdometry.between` gives the raw planar motion ``u = (dx, dy, dtheta)`` of the base between
two times in the base frame at the first (the convention of :mod:`gtvo.wheel_calibration.motions`:
``x1 = x0 (+) u``), interpolated between readings; :meth:`WheelOdometry.covers` says whether the
readings span the interval (a stream that starts late or ends early does not cover the keyframes
outside it: they get no wheel factor). :func:`simulate_wheel_odometry` makes the readings that a
robot with a given calibration error and noise would log along a known camera trajectory.

Pure numpy; the planar motion math is :mod:`gtvo.wheel_calibration` 's (imported when used, so that
opening a sequence does not load GTSAM).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.config.sections.wheel import DEFAULT_NOMINAL_BASELINE
from gtvo.core.lie import invert_poses
from gtvo.errors import InputError, show

FloatArray = NDArray[np.float64]
WheelKind = Literal["pose", "arcs"]

#: Columns of each kind, in the order of ``values`` (and of the CSV header, after ``time``).
WHEEL_COLUMNS: dict[str, tuple[str, ...]] = {"pose": ("x", "y", "theta"), "arcs": ("left", "right")}


def check_readings(times: ArrayLike, values: ArrayLike, kind: str, source: str,
                   rows: ArrayLike | None = None, row_name: str = "row",
                   max_gap: float | None = None, max_speed: float | None = None) -> tuple[FloatArray, FloatArray]:
    """``(times, values)`` as float arrays, checked: (N,) times strictly increasing, (N, 2) or (N, 3)
    values of ``kind``, all finite, (with ``max_gap``) no gap longer than ``max_gap`` seconds and
    (with ``max_speed``) no faster motion (:func:`check_speed`).

    Raises:
        InputError: one line naming ``source`` and the first bad reading (:func:`reading_error`;
            ``rows``: the file's line numbers or the bag's message numbers; default the index).
    """
    if kind not in WHEEL_COLUMNS:
        raise InputError(f"wheel odometry kind must be 'pose' or 'arcs', got {show(kind)}", source)
    checked = check_timed_readings(times, [(values, WHEEL_COLUMNS[kind])], f"wheel odometry ({kind})", "reading",
                                   source, rows, row_name, max_gap, "wheel.max_gap: longer gaps are not interpolated")
    t, (v,) = checked.times, checked.values
    if max_speed is not None:
        check_speed(t, v, kind, source, checked.rows, row_name, max_speed)
    return t, v


@dataclass(frozen=True)
class CheckedReadings:
    """Timed readings that passed :func:`check_timed_readings`.

    Attributes:
        times: (N,) seconds, strictly increasing.
        values: each block of columns as an (N, width) float array, in the order given.
        rows: (N,) what each reading is called in messages (a file's line numbers, a bag's message
            numbers, or the index).
        source: the file or ``bag:/topic`` the readings came from.
        row_name: ``"line"``, ``"message"``, ``"row"`` or ``"reading"``.
    """

    times: FloatArray
    values: list[FloatArray]
    rows: NDArray[np.int64]
    source: str
    row_name: str

    def refuse(self, i: int, message: str) -> InputError:
        """The refusal of reading ``i`` (:func:`reading_error`)."""
        return reading_error(message, self.source, self.row_name, int(self.rows[i]))


def check_timed_readings(times: ArrayLike, blocks: Sequence[tuple[ArrayLike, tuple[str, ...]]], what: str,
                         noun: str, source: str, rows: ArrayLike | None = None, row_name: str = "row",
                         max_gap: float | None = None, gap_setting: str = "") -> CheckedReadings:
    """The checks every stream of timed readings beside the images passes (the wheels' and the IMU's
    readers share them): each block ``(values, column names)`` of shape (N, len(names)) for N times,
    at least 2 readings, all finite, times strictly increasing and (with ``max_gap``) no gap longer
    than ``max_gap`` seconds. ``what`` names the stream in the shape refusal (``"an IMU"``), ``noun``
    one reading (``"IMU reading"``), ``gap_setting`` the setting that bounds the gap.

    Raises:
        InputError: one line naming ``source`` and the first bad reading (:func:`reading_error`;
            ``rows``: the file's line numbers or the bag's message numbers; default the index).
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    values = [np.asarray(v, dtype=np.float64) for v, _ in blocks]
    names = [n for _, n in blocks]
    if any(v.shape != (t.size, len(n)) for v, n in zip(values, names)):
        wanted = " and ".join(f"{len(n)} values ({', '.join(n)})" for n in names)
        got = " and ".join(str(v.shape) for v in values)
        raise InputError(f"{what} needs {t.size} rows of {wanted}, got shape{'s' if len(values) > 1 else ''} {got}",
                         source)
    if t.size < 2:
        raise InputError(f"{what} needs at least 2 readings, got {t.size}", source)
    where = np.arange(t.size) if rows is None else np.asarray(rows).reshape(-1)
    checked = CheckedReadings(t, values, where, source, row_name)
    bad = ~np.isfinite(t)
    for v in values:
        bad |= ~np.isfinite(v).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        reading = [float(t[i]), *np.concatenate([v[i] for v in values]).tolist()]
        columns = ", ".join(c for n in names for c in n)
        raise checked.refuse(i, f"not a finite {noun} (time, {columns} = {show(reading)})")
    step = np.diff(t)
    if np.any(step <= 0):
        i = int(np.flatnonzero(step <= 0)[0]) + 1
        raise checked.refuse(i, f"time {t[i]:.9g} s is not after the previous {noun}'s {t[i - 1]:.9g} s "
                                "(times must be strictly increasing)")
    if max_gap is not None:
        check_gaps(checked, max_gap, noun, gap_setting)
    return checked


def check_gaps(checked: CheckedReadings, max_gap: float, noun: str, gap_setting: str) -> None:
    """Refuse readings (:func:`check_timed_readings`) with a gap longer than ``max_gap`` seconds.

    Raises:
        InputError: one line naming the reading after the gap.
    """
    step = np.diff(checked.times)
    if np.any(step > max_gap):
        i = int(np.flatnonzero(step > max_gap)[0]) + 1
        raise checked.refuse(i, f"a gap of {step[i - 1]:.4g} s since the previous {noun} (at most {max_gap:g} s: "
                                f"{gap_setting})")


def check_speed(times: FloatArray, values: FloatArray, kind: str, source: str, rows: ArrayLike,
                row_name: str, max_speed: float) -> None:
    """Refuse readings (checked by :func:`check_readings`; arcs in metres) in which a wheel (arcs) or
    the base (pose) moves faster than ``max_speed`` m/s between two readings: a unit error (ticks
    without ``wheel.tick_scale``, millimetres) that would otherwise pass as a wildly wrong calibration.

    Raises:
        InputError: one line naming ``source`` and the reading (:func:`reading_error`).
    """
    d = np.diff(values, axis=0)
    moved = np.abs(d).max(axis=1) if kind == "arcs" else np.hypot(d[:, 0], d[:, 1])
    speed = moved / np.diff(times)
    if np.any(speed > max_speed):
        i = int(np.flatnonzero(speed > max_speed)[0])
        what = "a wheel" if kind == "arcs" else "the base"
        hint = ("encoder ticks? set wheel.tick_scale (m per tick)" if kind == "arcs"
                else "not metres? the pose must be in metres and radians")
        raise reading_error(f"{what} moved {moved[i]:.4g} m in {times[i + 1] - times[i]:.4g} s ({speed[i]:.4g} m/s, "
                            f"more than wheel.max_speed {max_speed:g} m/s): {hint}", source, row_name,
                            int(np.asarray(rows).reshape(-1)[i + 1]))


def reading_error(message: str, source: str, row_name: str, row: int) -> InputError:
    """The refusal of one reading: ``<file>:<line>: message`` for a file's line (``row_name`` "line"),
    the form of every other file error, else ``<source>: <row_name> <row>: message`` (a bag's
    message number, an array's index)."""
    if row_name == "line":
        return InputError(message, source, row)
    return InputError(f"{row_name} {row}: {message}", source)


@dataclass(frozen=True, eq=False)
class WheelOdometry:
    """Raw wheel-odometry readings of a ground robot's base, in the sequence's clock.

    Attributes:
        times: (N,) seconds, strictly increasing.
        kind: ``"pose"`` or ``"arcs"`` (module doc).
        values: (N, 3) planar base pose ``x, y, theta`` (REP 103, theta unwrapped) or (N, 2)
            cumulative left / right wheel arcs in metres.
        source: the file path or ``"bag:/topic"``, for messages.
        nominal_baseline: the nominal track width b0 (m): needed to turn arcs into motion.
        base_to_camera: ``T_base_cam`` (4x4) found with the readings (a bag's ``/tf_static``), or
            None: the config's ``wheel.base_to_camera`` holds.
    """

    times: FloatArray
    kind: WheelKind
    values: FloatArray
    source: str
    nominal_baseline: float | None = None
    base_to_camera: FloatArray | None = None

    def __post_init__(self) -> None:
        t, v = check_readings(self.times, self.values, self.kind, self.source, row_name="reading")
        if self.kind == "pose":
            v = v.copy()
            v[:, 2] = np.unwrap(v[:, 2])
        object.__setattr__(self, "times", t)
        object.__setattr__(self, "values", v)
        b0 = self.nominal_baseline
        if b0 is not None and not (np.isfinite(b0) and b0 > 0):
            raise InputError(f"the nominal baseline must be a positive length (m), got {show(b0)}", self.source)
        if self.kind == "arcs" and b0 is None:
            raise InputError("wheel arcs need the nominal baseline (wheel.nominal_baseline, m) to give motion",
                             self.source)
        if self.base_to_camera is not None:
            T = np.asarray(self.base_to_camera, dtype=np.float64)
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise InputError(f"base_to_camera must be a finite 4x4 transform, got shape {T.shape}", self.source)
            object.__setattr__(self, "base_to_camera", T)

    def __len__(self) -> int:
        return int(self.times.size)

    def covers(self, t0: float, t1: float) -> bool:
        """True when the readings span ``[t0, t1]`` (``t0 <= t1``), so :meth:`between` interpolates
        and never extrapolates."""
        return bool(self.times[0] <= t0 <= t1 <= self.times[-1])

    def at(self, t: ArrayLike) -> FloatArray:
        """The readings linearly interpolated at the times ``t`` (inside the readings), (..., 2|3)."""
        q = np.asarray(t, dtype=np.float64)
        if np.any(q < self.times[0]) or np.any(q > self.times[-1]):
            raise InputError(f"time(s) outside the wheel odometry's {self.times[0]:.6f}..{self.times[-1]:.6f} s",
                             self.source)
        return np.stack([np.interp(q, self.times, self.values[:, k]) for k in range(self.values.shape[1])],
                        axis=-1)

    def between(self, t0: float, t1: float) -> FloatArray:
        """Raw planar motion ``u = (dx, dy, dtheta)`` of the base from ``t0`` to ``t1``, in the base frame
        at ``t0`` (``x1 = x0 (+) u``, :mod:`gtvo.wheel_calibration.motions`).

        Pose kind: from the poses interpolated at ``t0`` and ``t1`` (theta linearly in its unwrapped
        value). Arcs kind: the arc model of :mod:`factors.odometry_calibration` with the nominal
        baseline (``s = (dl + dr) / 2``, ``dtheta = (dr - dl) / b0``).
        """
        if not self.covers(t0, t1):
            raise InputError(f"the wheel odometry ({self.times[0]:.6f}..{self.times[-1]:.6f} s) does not cover "
                             f"{t0:.6f}..{t1:.6f} s", self.source)
        ends = self.at([t0, t1])
        if self.kind == "pose":
            from gtvo.wheel_calibration.motions import relative_motions  # noqa: PLC0415

            u = relative_motions(ends)[0]
            u[2] = ends[1, 2] - ends[0, 2]  # unwrapped: a turn is not folded into (-pi, pi]
            return u
        from gtvo.wheel_calibration.diff_drive import diff_drive_motions_from_arcs  # noqa: PLC0415

        d = ends[1] - ends[0]
        assert self.nominal_baseline is not None
        return diff_drive_motions_from_arcs(d[:1], d[1:], self.nominal_baseline)[0]


    def steps(self) -> FloatArray:
        """(N-1, 3) raw motions between consecutive readings (:meth:`between` of each pair)."""
        if self.kind == "arcs":
            from gtvo.wheel_calibration.diff_drive import diff_drive_motions_from_arcs  # noqa: PLC0415

            d = np.diff(self.values, axis=0)
            assert self.nominal_baseline is not None
            return diff_drive_motions_from_arcs(d[:, 0], d[:, 1], self.nominal_baseline)
        from gtvo.wheel_calibration.motions import relative_motions  # noqa: PLC0415

        u = relative_motions(self.values)
        u[:, 2] = np.diff(self.values[:, 2])
        return u

    def as_kind(self, kind: WheelKind) -> "WheelOdometry":
        """The same readings as ``kind``: arcs integrated to the pose the robot computes from them
        (the arc model, nominal baseline), or poses as the arcs of each step's arc (exact when each
        step is one arc: ``factors.odometry_calibration.wheel_arcs``)."""
        if kind == self.kind:
            return self
        if self.nominal_baseline is None:
            raise InputError("converting poses to wheel arcs needs the nominal baseline", self.source)
        from gtvo.wheel_calibration.motions import integrate_motions  # noqa: PLC0415

        if kind == "pose":
            values = integrate_motions(self.steps())
        else:
            from factors.odometry_calibration import wheel_arcs  # noqa: PLC0415

            arcs = np.column_stack(wheel_arcs(self.steps(), self.nominal_baseline))
            values = np.concatenate([np.zeros((1, 2)), np.cumsum(arcs, axis=0)])
        return WheelOdometry(self.times, kind, values, self.source, self.nominal_baseline, self.base_to_camera)


# ------------------------------------------------------------------------------------------ simulation


def planar_base_poses(T_world_cam: ArrayLike, T_base_cam: ArrayLike) -> FloatArray:
    """(N, 3) planar poses ``(x, y, theta)`` of the base in its odometry frame (the base's pose at the
    first time, REP 105), from the camera poses: ``T_world_base = T_world_cam T_base_cam^-1``,
    projected on the first base's x-y plane (theta: yaw about its z, unwrapped)."""
    Twc = np.asarray(T_world_cam, dtype=np.float64).reshape(-1, 4, 4)
    Tbc = np.asarray(T_base_cam, dtype=np.float64).reshape(4, 4)
    T_world_base = Twc @ invert_poses(Tbc[None])[0]
    T_odom_base = invert_poses(T_world_base[:1])[0] @ T_world_base
    theta = np.unwrap(np.arctan2(T_odom_base[:, 1, 0], T_odom_base[:, 0, 0]))
    return np.column_stack([T_odom_base[:, 0, 3], T_odom_base[:, 1, 3], theta])


def _raw_steps(true_steps: FloatArray, calibration: FloatArray, kind: str, b0: float | None) -> FloatArray:
    """Per-step raw readings' increments: (M, 3) motions (linear model, or pose kind) or (M, 2) arcs."""
    from factors.odometry_calibration import wheel_arcs  # noqa: PLC0415
    from gtvo.wheel_calibration.diff_drive import diff_drive_motions_from_arcs  # noqa: PLC0415

    if calibration.shape == (3, 3):  # linear: u_true = X u_raw
        raw = np.linalg.solve(calibration, true_steps.T).T
        return raw if kind == "pose" else np.column_stack(wheel_arcs(raw, b0))
    k_l, k_r, k_b = calibration
    s_l, s_r = wheel_arcs(true_steps, k_b * b0)  # the true wheels' arcs, on the true axle
    arcs = np.column_stack([s_l / k_l, s_r / k_r])  # what the nominal radii count
    return arcs if kind == "arcs" else diff_drive_motions_from_arcs(arcs[:, 0], arcs[:, 1], b0)


def simulate_wheel_odometry(times: ArrayLike, T_world_cam: ArrayLike, T_base_cam: ArrayLike, kind: WheelKind,
                            calibration: ArrayLike, noise: float | ArrayLike = 0.0, seed: int = 0,
                            nominal_baseline: float | None = None, source: str = "simulated") -> WheelOdometry:
    """The raw wheel readings a robot would log along a known trajectory, after a calibration error and noise.

    Args:
        times: (N,) seconds of the readings.
        T_world_cam: (N, 4, 4) camera poses at ``times``; the base's are ``T_world_cam @ inv(T_base_cam)``
            and its true planar motion between readings is :func:`planar_base_poses`' .
        T_base_cam: the camera's pose on the base (4x4).
        kind: ``"pose"`` (the robot's integrated planar pose) or ``"arcs"`` (cumulative wheel arcs).
        calibration: the true calibration, that a calibrated model recovers: a 3x3 ``X`` of the linear
            model (``u_true = X u_raw`` per step, so ``u_raw = X^-1 u_true``), or the diff-drive
            ``(k_L, k_R, k_b)`` (true radii and axle over the nominal ones: the wheels count
            ``true arc / k``, the robot integrates them with the nominal baseline ``b0``).
        noise: standard deviation of each step's increment: arcs, a scalar or (left, right) in metres;
            pose, a scalar or ``(dx, dy, dtheta)`` in metres and radians (i.i.d. Gaussian, per reading).
        seed: the noise's seed.
        nominal_baseline: b0 (m); needed for arcs and for the diff-drive model.
        source: the name in messages.
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    poses = planar_base_poses(T_world_cam, T_base_cam)
    if poses.shape[0] != t.size:
        raise InputError(f"{t.size} times but {poses.shape[0]} camera poses", source)
    cal = np.asarray(calibration, dtype=np.float64)
    if cal.shape not in ((3, 3), (3,)) or not np.all(np.isfinite(cal)):
        raise InputError(f"calibration must be a 3x3 X or (k_L, k_R, k_b), got {show(cal.tolist())}", source)
    if (kind == "arcs" or cal.shape == (3,)) and nominal_baseline is None:
        raise InputError("simulated wheel arcs and the diff-drive model need the nominal baseline", source)
    from gtvo.wheel_calibration.motions import integrate_motions, relative_motions  # noqa: PLC0415

    true_steps = relative_motions(poses)
    true_steps[:, 2] = np.diff(poses[:, 2])  # unwrapped, as the poses
    steps = _raw_steps(true_steps, cal, kind, nominal_baseline)
    sigma = np.broadcast_to(np.asarray(noise, dtype=np.float64), (steps.shape[1],))
    if np.any(sigma > 0):
        steps = steps + np.random.default_rng(int(seed)).normal(0.0, 1.0, steps.shape) * sigma
    if kind == "arcs":
        values = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    else:
        values = integrate_motions(steps)
    return WheelOdometry(t, kind, values, source, nominal_baseline)
