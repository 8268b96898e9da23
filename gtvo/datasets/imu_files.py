"""IMU files beside a sequence (docs/imu.md, "IMU input"): the readings' CSV, EuRoC's ``sensor.yaml``,
Kalibr's ``imu.yaml`` and ``camchain-imucam.yaml``, and the rule that puts them together.

The readings, one CSV with a header line:

* plain: ``time,wx,wy,wz,ax,ay,az``: seconds in the images' clock, rad/s, m/s^2 (gravity included);
* EuRoC / ASL: ``#timestamp [ns],w_RS_S_x [rad s^-1],...,a_RS_S_z [m s^-2]``: nanoseconds, the same
  units and order.

What a log folder holds is found by :func:`find_imu_files`: ``imu0/data.csv`` (and its
``imu0/sensor.yaml``) in the folder or its ``mav0/``, and Kalibr's ``*camchain-imucam.yaml`` and
``*imu.yaml`` in the folder. Each item is taken from the first that gives it:

* noise densities and random walks: Kalibr's ``imu.yaml``, ``imu0/sensor.yaml``, the config's
  ``imu:`` section, else EuRoC's ADIS16448 (:data:`gtvo.datasets.imu.DEFAULT_NOISE`);
* ``T_cam_imu``: Kalibr's ``camchain-imucam.yaml`` (``cam0.T_cam_imu``), ``imu0/sensor.yaml``'s
  ``T_BS`` composed with the left camera's (EuRoC: both in the body frame; beside a KITTI-layout
  folder the body frame is the left camera), the config's ``imu.T_cam_imu``; none of them: refused;
* the time shift: Kalibr's ``cam0.timeshift_cam_imu``, else ``imu.time_shift`` (s).

EuRoC's yaml files are OpenCV yaml (``%YAML:1.0``) and may repeat a key; the last value holds, as
in OpenCV's reader.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from gtvo.config.sections.imu import ImuConfig
from gtvo.core.lie import pose_from_xyz_quaternion
from gtvo.datasets._common import parse_float_table, read_rows, require_file
from gtvo.datasets.imu import (DEFAULT_NOISE, IMU_COLUMNS, MAX_GAP_S, MIN_RATE_HZ, FloatArray, ImuMeasurements,
                               ImuNoise, check_imu_readings)
from gtvo.errors import InputError, show

#: The readings' file of an IMU beside a sequence (EuRoC's name).
IMU_CSV = Path("imu0") / "data.csv"
#: Its sensor description beside it.
IMU_SENSOR_YAML = Path("imu0") / "sensor.yaml"
#: The EuRoC header's column names (after the timestamp), for recognising the file.
EUROC_IMU_HEADER = ("w_rs_s_x", "w_rs_s_y", "w_rs_s_z", "a_rs_s_x", "a_rs_s_y", "a_rs_s_z")
_NOISE_KEYS = ("gyroscope_noise_density", "accelerometer_noise_density", "gyroscope_random_walk",
               "accelerometer_random_walk")


@dataclass(frozen=True)
class ImuReadOptions:
    """What turns logged IMU readings into :class:`ImuMeasurements` where the files are silent (the
    config's ``imu:`` section, :func:`imu_read_options`).

    Attributes:
        enabled: False: no IMU is read (``--no-imu``).
        topic: the bag topic (``--imu-topic``); None: the one ``sensor_msgs/Imu`` topic.
        noise: the noise model when no file gives one; None: :data:`DEFAULT_NOISE`.
        T_cam_imu: the IMU's pose in the left camera when no file gives it (4x4), or None.
        time_shift: seconds subtracted from the IMU's times when no file gives it.
        min_rate: the lowest median rate accepted (Hz).
        max_gap: the longest gap between readings accepted (s).
    """

    enabled: bool = True
    topic: str | None = None
    noise: ImuNoise | None = None
    T_cam_imu: FloatArray | None = None
    time_shift: float = 0.0
    min_rate: float = MIN_RATE_HZ
    max_gap: float = MAX_GAP_S


def imu_read_options(config: ImuConfig) -> ImuReadOptions:
    """The settings the IMU readers take, from the config's ``imu:`` section (the readers'
    ``imu_options``, :func:`gtvo.datasets.open_sequence`)."""
    noise = None
    if config.gyro_noise_density is not None:
        noise = ImuNoise(config.gyro_noise_density, config.accel_noise_density, config.gyro_random_walk,  # type: ignore[arg-type]
                         config.accel_random_walk, "config imu:")  # type: ignore[arg-type]
    T = None if config.imu_in_camera is None else pose_from_xyz_quaternion(config.imu_in_camera)
    return ImuReadOptions(enabled=config.enabled, topic=config.topic, noise=noise, T_cam_imu=T,
                          time_shift=config.time_shift, min_rate=config.min_rate, max_gap=config.max_gap)


@dataclass(frozen=True)
class ImuCalibration:
    """What calibration files said about an IMU (None: silent)."""

    noise: ImuNoise | None = None
    T_cam_imu: FloatArray | None = None
    time_shift: float | None = None
    extrinsic_source: str = ""


def load_yaml_mapping(path: Path, what: str) -> dict:
    """A yaml file's mapping (OpenCV's ``%YAML:1.0`` line dropped; a repeated key keeps its last value).

    Raises:
        InputError: unreadable, malformed or not a mapping, naming the file (and line).
    """
    require_file(path, what)
    text = path.read_text(encoding="utf-8", errors="replace")
    text = "\n".join("" if line.startswith("%YAML") else line for line in text.splitlines())
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise InputError(f"malformed yaml ({getattr(exc, 'problem', 'parse error')})", path=path,
                         line=None if mark is None else mark.line + 1) from None
    if not isinstance(data, dict):
        raise InputError(f"not a {what} (no mapping)", path=path)
    return data


def _matrix(value: object, key: str, path: Path) -> FloatArray:
    """A 4x4 matrix from a list of 4 rows, a flat list of 16 or an OpenCV ``{rows, cols, data}``."""
    if isinstance(value, dict):
        value = value.get("data")
    try:
        T = np.asarray(value, dtype=np.float64).reshape(4, 4)
    except (TypeError, ValueError):
        raise InputError(f"{key} must be a 4x4 matrix (4 rows of 4 numbers, or 16 numbers), got {show(value)}",
                         path=path) from None
    if not np.all(np.isfinite(T)):
        raise InputError(f"{key} contains NaN or infinite values", path=path)
    return T


def _noise(data: dict, path: Path) -> ImuNoise | None:
    """The four noise numbers of a Kalibr / EuRoC mapping; None when it has none of them."""
    present = [k for k in _NOISE_KEYS if k in data]
    if not present:
        return None
    missing = [k for k in _NOISE_KEYS if k not in data]
    if missing:
        raise InputError(f"has {', '.join(present)} but not {', '.join(missing)}", path=path)
    values = []
    for k in _NOISE_KEYS:
        try:
            values.append(float(data[k]))
        except (TypeError, ValueError):
            raise InputError(f"{k} must be a number, got {show(data[k])}", path=path) from None
    return ImuNoise(*values, source=str(path))


def read_euroc_imu_yaml(path: Path) -> tuple[ImuNoise | None, FloatArray]:
    """``(noise, T_BS)`` of an EuRoC ``imu0/sensor.yaml`` (``T_BS``: the IMU in the body frame;
    identity when absent)."""
    data = load_yaml_mapping(path, "IMU sensor.yaml")
    T_BS = _matrix(data["T_BS"], "T_BS", path) if "T_BS" in data else np.eye(4)
    return _noise(data, path), T_BS


def read_kalibr_imu_yaml(path: Path) -> ImuNoise:
    """The noise model of a Kalibr ``imu.yaml`` (its ``imu0:`` entry, or the top level)."""
    data = load_yaml_mapping(path, "Kalibr imu.yaml")
    entry = data.get("imu0", data)
    noise = _noise(entry if isinstance(entry, dict) else {}, path)
    if noise is None:
        raise InputError(f"no IMU noise model ({', '.join(_NOISE_KEYS)})", path=path)
    return noise


def read_kalibr_camchain(path: Path) -> tuple[FloatArray, float]:
    """``(T_cam_imu, timeshift_cam_imu)`` of ``cam0`` in a Kalibr ``camchain-imucam.yaml``."""
    data = load_yaml_mapping(path, "Kalibr camchain-imucam.yaml")
    cam0 = data.get("cam0")
    if not isinstance(cam0, dict) or "T_cam_imu" not in cam0:
        raise InputError("no cam0.T_cam_imu (a camchain-imucam.yaml from kalibr_calibrate_imu_camera)", path=path)
    shift = cam0.get("timeshift_cam_imu", 0.0)
    if not isinstance(shift, (int, float)) or not np.isfinite(shift):
        raise InputError(f"cam0.timeshift_cam_imu must be a number (s), got {show(shift)}", path=path)
    return _matrix(cam0["T_cam_imu"], "cam0.T_cam_imu", path), float(shift)


def read_imu_table(path: Path, options: ImuReadOptions = ImuReadOptions()) -> tuple[FloatArray, FloatArray,
                                                                                         FloatArray]:
    """``(times in s as logged, gyro, accel)`` of an IMU CSV (module doc), checked.

    Raises:
        InputError: one line naming the file and the line (header, width, number, and
            :func:`gtvo.datasets.imu.check_imu_readings`'s refusals).
    """
    require_file(path, "IMU csv")
    try:
        first = path.read_text(encoding="utf-8", errors="replace").splitlines()[:1]
    except OSError as exc:
        raise InputError(f"cannot read ({exc.__class__.__name__})", path=path) from None
    header = [f.strip().lower() for f in (first[0] if first else "").lstrip("#").split(",")]
    names = [h.split("[")[0].strip() for h in header]
    if names == ["time", *IMU_COLUMNS]:
        scale = 1.0
    elif len(names) == 7 and names[0] == "timestamp" and tuple(names[1:]) == EUROC_IMU_HEADER:
        scale = 1e-9
    else:
        raise InputError(f"the header is {first[0] if first else ''!r}: expected time,wx,wy,wz,ax,ay,az (s, rad/s, "
                         "m/s^2) or EuRoC's #timestamp [ns],w_RS_S_x [rad s^-1],...", path, 1)
    rows = [r for r in read_rows(path, 1, delimiter=",") if r.line != 1]
    if not rows:
        raise InputError("no IMU readings after the header", path)
    for row in rows:
        if len(row.fields) != 7:
            raise InputError(f"expected 7 values (time, wx, wy, wz, ax, ay, az), got {len(row.fields)}", path, row.line)
    lines = [r.line for r in rows]
    if scale == 1e-9:
        stamps = np.array([int(r.fields[0]) if r.fields[0].lstrip("-").isdigit() else np.nan for r in rows],
                          dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(stamps))
        if bad.size:
            raise InputError(f"not an integer nanosecond timestamp: {rows[bad[0]].fields[0]!r}", path, lines[bad[0]])
        table = np.column_stack([stamps * 1e-9, _floats(rows, path)])
    else:
        table = np.column_stack([_floats_col0(rows, path), _floats(rows, path)])
    return check_imu_readings(table[:, 0], table[:, 1:4], table[:, 4:7], str(path), rows=lines, row_name="line",
                              min_rate=options.min_rate, max_gap=options.max_gap)


def _floats(rows: list, path: Path) -> FloatArray:
    """Columns 1..6 as floats; NaN is kept (the reading check names its line)."""
    out = np.empty((len(rows), 6))
    for k, row in enumerate(rows):
        try:
            out[k] = [float(f) for f in row.fields[1:]]
        except ValueError:
            bad = next(f for f in row.fields[1:] if not _is_number(f))
            raise InputError(f"not a number: {bad!r}", path, row.line) from None
    return out


def _floats_col0(rows: list, path: Path) -> FloatArray:
    out = np.empty(len(rows))
    for k, row in enumerate(rows):
        if not _is_number(row.fields[0]):
            raise InputError(f"not a number: {row.fields[0]!r}", path, row.line)
        out[k] = float(row.fields[0])
    return out


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def find_imu_files(folder: Path) -> tuple[Path | None, Path | None, Path | None, Path | None]:
    """``(data.csv, imu0/sensor.yaml, Kalibr imu.yaml, Kalibr camchain-imucam.yaml)`` beside a
    sequence folder (module doc); None for what is not there."""
    csv = sensor = None
    for base in (folder, folder / "mav0"):
        if (base / IMU_CSV).is_file():
            csv = base / IMU_CSV
            sensor = base / IMU_SENSOR_YAML if (base / IMU_SENSOR_YAML).is_file() else None
            break
    chains = sorted(folder.glob("*camchain-imucam.yaml")) if folder.is_dir() else []
    imus = sorted(p for p in folder.glob("*imu.yaml") if "camchain" not in p.name) if folder.is_dir() else []
    return csv, sensor, (imus[0] if imus else None), (chains[0] if chains else None)


def kalibr_calibration(imu_yaml: Path | None, camchain: Path | None) -> ImuCalibration:
    """What Kalibr's files beside a log say (module doc)."""
    noise = None if imu_yaml is None else read_kalibr_imu_yaml(imu_yaml)
    if camchain is None:
        return ImuCalibration(noise)
    T, shift = read_kalibr_camchain(camchain)
    return ImuCalibration(noise, T, shift, str(camchain))


def imu_from_table(times: FloatArray, gyro: FloatArray, accel: FloatArray, source: str, options: ImuReadOptions,
                   *calibrations: ImuCalibration) -> ImuMeasurements:
    """:class:`ImuMeasurements` from checked readings and the first of ``calibrations`` (then
    ``options``) that gives each item (module doc).

    Raises:
        InputError: no extrinsic anywhere, naming ``source``.
    """
    noise = next((c.noise for c in calibrations if c.noise is not None), options.noise or DEFAULT_NOISE)
    with_T = next((c for c in calibrations if c.T_cam_imu is not None), None)
    if with_T is not None:
        T, extrinsic = with_T.T_cam_imu, with_T.extrinsic_source
    elif options.T_cam_imu is not None:
        T, extrinsic = options.T_cam_imu, "config imu.T_cam_imu"
    else:
        raise InputError("the IMU's pose on the camera is not given: add a Kalibr camchain-imucam.yaml, an "
                         "imu0/sensor.yaml with T_BS, or imu.T_cam_imu in the config (docs/imu.md)", source)
    shift = next((c.time_shift for c in calibrations if c.time_shift is not None), options.time_shift)
    return ImuMeasurements(times - shift, gyro, accel, noise, T, source, shift, extrinsic, _checked=True)


def read_imu_folder(folder: Path, options: ImuReadOptions, T_body_cam: FloatArray | None = None,
                    csv: Path | None = None) -> ImuMeasurements | None:
    """The IMU beside a sequence folder (module doc), or None when it has none (or ``options``
    disable it).

    Args:
        folder: the sequence folder (or a bag's folder, for Kalibr's files).
        options: the config's ``imu:`` section.
        T_body_cam: the left (rectified) camera's pose in the body frame of ``imu0/sensor.yaml``'s
            ``T_BS`` (EuRoC); None: the body frame is the left camera.
        csv: an IMU CSV to use instead of the folder's ``imu0/data.csv`` (``--imu FILE``).
    """
    if not options.enabled:
        return None
    found, sensor, imu_yaml, camchain = find_imu_files(folder)
    csv = csv if csv is not None else found
    if csv is None:
        return None
    if csv != found:
        sensor = csv.parent / "sensor.yaml" if (csv.parent / "sensor.yaml").is_file() else None
    times, gyro, accel = read_imu_table(csv, options)
    calibrations = [kalibr_calibration(imu_yaml, camchain)]
    if sensor is not None:
        noise, T_BS = read_euroc_imu_yaml(sensor)
        T_body_cam = np.eye(4) if T_body_cam is None else T_body_cam
        calibrations.append(ImuCalibration(noise, np.linalg.inv(T_body_cam) @ T_BS, None, str(sensor)))
    return imu_from_table(times, gyro, accel, str(csv), options, *calibrations)


def write_imu_files(imu: ImuMeasurements, folder: Path) -> Path:
    """Write ``imu`` as ``imu0/data.csv`` (EuRoC's nanosecond layout) and ``imu0/sensor.yaml`` (its
    noise model, rate and ``T_BS = T_cam_imu``: the body frame is the left camera) under ``folder``;
    :func:`read_imu_folder` reads them back. Returns the ``imu0`` folder."""
    out = Path(folder) / "imu0"
    out.mkdir(parents=True, exist_ok=True)
    stamps = np.rint((imu.times + imu.time_shift) * 1e9).astype(np.int64)
    lines = ["#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
             "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"]
    lines += [f"{s}," + ",".join(f"{v:.17g}" for v in (*w, *a)) for s, w, a in zip(stamps, imu.gyro, imu.accel)]
    (out / "data.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    n = imu.noise
    T = ", ".join(f"{v:.17g}" for v in imu.T_cam_imu.reshape(-1))
    (out / "sensor.yaml").write_text(
        "%YAML:1.0\nsensor_type: imu\ncomment: \"gtvo synthetic IMU; T_BS is the IMU in the left camera frame\"\n"
        f"T_BS:\n  cols: 4\n  rows: 4\n  data: [{T}]\nrate_hz: {imu.rate_hz:.6g}\n"
        f"gyroscope_noise_density: {n.gyro_noise_density:.9g}\naccelerometer_noise_density: {n.accel_noise_density:.9g}\n"
        f"gyroscope_random_walk: {n.gyro_random_walk:.9g}\naccelerometer_random_walk: {n.accel_random_walk:.9g}\n",
        encoding="utf-8")
    return out
