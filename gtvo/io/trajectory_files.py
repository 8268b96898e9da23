"""Trajectory files: TUM, KITTI and EuRoC ground-truth csv (readers), TUM and KITTI (writers).

Formats (one pose per line; blank lines and everything after ``#`` are ignored):

* **TUM**: ``t tx ty tz qx qy qz qw``: time in seconds, position, unit quaternion
  (Hamilton, scalar last) of ``T_world_cam``.
* **KITTI**: 12 numbers, the first three rows of ``T_world_cam`` row-major
  (``r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz``); times come from an optional separate file
  with one time in seconds per line (KITTI's ``times.txt``); without it the frame index is
  used as the time (0, 1, 2, ...).
* **EuRoC** ``state_groundtruth_estimate0/data.csv``: comma-separated
  ``t_ns, px, py, pz, qw, qx, qy, qz, ...`` (note: scalar first); further columns ignored.
  Time is ``t_ns / 1e9`` in seconds (as evo reads it; float64 seconds near 1.4e9 resolve
  about 0.24 microseconds).

Every bad line raises :class:`InputError` naming ``file:line``: a wrong number of values, a
value that is not a number, NaN or infinity, a quaternion whose norm is not within
:data:`QUATERNION_NORM_TOLERANCE` of 1 (it is then normalised), a rotation block that is not a
rotation within :data:`ROTATION_TOLERANCE`, a time that goes backwards. Writers print
``repr`` of every float (the shortest text that reads back to the identical double), single
spaces, no trailing delimiter (evo's readers need that), and write atomically.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from gtvo.core.atomic import write_text
from gtvo.errors import InputError, not_a_file
from gtvo.evaluation.trajectory import Trajectory
from gtvo.core.lie import (QUATERNION_NORM_TOLERANCE, ROTATION_TOLERANCE, make_poses, not_a_rotation,
                           quaternions_to_rotations, rotation_defects)

TrajectoryFormat = Literal["tum", "kitti", "euroc", "auto"]


def _read_rows(path: Path, delimiter: str | None) -> tuple[list[int], list[list[str]]]:
    """Line numbers (1-based) and fields of the non-blank, non-comment lines."""
    if not path.is_file():
        raise not_a_file(path, "trajectory file")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"not a text file ({exc.reason})", path=path) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", path=path) from None
    numbers: list[int] = []
    rows: list[list[str]] = []
    for k, line in enumerate(text.splitlines(), start=1):
        content = line.split("#", 1)[0].strip()
        if not content:
            continue
        fields = content.split(delimiter) if delimiter else content.split()
        numbers.append(k)
        rows.append([f.strip() for f in fields])
    if not rows:
        raise InputError("no poses in file (empty or only comments)", path=path)
    return numbers, rows


def _to_matrix(path: Path, numbers: list[int], rows: list[list[str]], ncols: int, at_least: bool,
               what: str) -> NDArray[np.float64]:
    """Parse the rows into a float matrix of ``ncols`` columns, naming the first bad line."""
    for k, row in zip(numbers, rows):
        if (len(row) < ncols) if at_least else (len(row) != ncols):
            need = f"at least {ncols}" if at_least else f"{ncols}"
            raise InputError(f"{what} line needs {need} values, found {len(row)}", path=path, line=k)
    cut = [row[:ncols] for row in rows]
    try:
        mat = np.array(cut, dtype=np.float64)
    except ValueError:
        for k, row in zip(numbers, cut):
            for v in row:
                try:
                    float(v)
                except ValueError:
                    raise InputError(f"not a number: {v!r}", path=path, line=k) from None
        raise InputError("values could not be read as numbers", path=path) from None  # pragma: no cover
    bad = ~np.all(np.isfinite(mat), axis=1)
    if np.any(bad):
        raise InputError("NaN or infinite value", path=path, line=numbers[int(np.argmax(bad))])
    return mat


def _check_times(path: Path, numbers: list[int], t: NDArray[np.float64]) -> None:
    back = np.diff(t) < 0
    if np.any(back):
        k = int(np.argmax(back)) + 1
        raise InputError(f"time goes backwards ({float(t[k - 1])!r} -> {float(t[k])!r})", path=path, line=numbers[k])


def _rotations_from_quaternions(path: Path, numbers: list[int], q_xyzw: NDArray[np.float64]) -> NDArray[np.float64]:
    norm = np.linalg.norm(q_xyzw, axis=1)
    bad = np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE
    if np.any(bad):
        i = int(np.argmax(bad))
        raise InputError(f"quaternion is not unit length (norm {norm[i]:.6g})", path=path, line=numbers[i])
    return quaternions_to_rotations(q_xyzw)


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory file ``t tx ty tz qx qy qz qw`` (see the module docstring)."""
    path = Path(path)
    numbers, rows = _read_rows(path, None)
    mat = _to_matrix(path, numbers, rows, 8, False, "TUM")
    _check_times(path, numbers, mat[:, 0])
    R = _rotations_from_quaternions(path, numbers, mat[:, 4:8])
    return Trajectory(mat[:, 0], make_poses(R, mat[:, 1:4]), name=str(path))


def read_times(path: str | Path) -> NDArray[np.float64]:
    """Read a times file (one time in seconds per line, KITTI's ``times.txt``)."""
    path = Path(path)
    numbers, rows = _read_rows(path, None)
    t = _to_matrix(path, numbers, rows, 1, False, "times")[:, 0]
    _check_times(path, numbers, t)
    return t


def read_kitti(path: str | Path, times_path: str | Path | None = None) -> Trajectory:
    """Read a KITTI pose file (12 values per line), with times from ``times_path`` if given.

    Rotation blocks are kept as printed (not re-orthonormalised), but a block that is not a
    rotation within :data:`ROTATION_TOLERANCE` is rejected.
    """
    path = Path(path)
    numbers, rows = _read_rows(path, None)
    mat = _to_matrix(path, numbers, rows, 12, False, "KITTI")
    T = np.zeros((len(mat), 4, 4))
    T[:, :3, :] = mat.reshape(-1, 3, 4)
    T[:, 3, 3] = 1.0
    ortho, det = rotation_defects(T[:, :3, :3])
    bad = (ortho > ROTATION_TOLERANCE) | (det <= 0)
    if np.any(bad):
        i = int(np.argmax(bad))
        raise InputError(f"rotation block {not_a_rotation(ortho[i], det[i])}", path=path, line=numbers[i])
    if times_path is None:
        t = np.arange(len(mat), dtype=np.float64)
    else:
        t = read_times(times_path)
        if t.size != len(mat):
            raise InputError(f"times file has {t.size} times but {path} has {len(mat)} poses", path=times_path)
    return Trajectory(t, T, name=str(path))


def read_euroc_csv(path: str | Path) -> Trajectory:
    """Read EuRoC ground truth ``data.csv`` (``t_ns, p, q_wxyz, ...``; see the module docstring)."""
    path = Path(path)
    numbers, rows = _read_rows(path, ",")
    mat = _to_matrix(path, numbers, rows, 8, True, "EuRoC csv")
    t = mat[:, 0] / 1e9
    _check_times(path, numbers, t)
    q_xyzw = mat[:, [5, 6, 7, 4]]
    R = _rotations_from_quaternions(path, numbers, q_xyzw)
    return Trajectory(t, make_poses(R, mat[:, 1:4]), name=str(path))


def detect_format(path: str | Path) -> Literal["tum", "kitti", "euroc"]:
    """Guess the format: ``.csv`` -> EuRoC; otherwise 8 values per line -> TUM, 12 -> KITTI."""
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return "euroc"
    numbers, rows = _read_rows(path, None)
    n = len(rows[0])
    if n == 8:
        return "tum"
    if n == 12:
        return "kitti"
    raise InputError(f"cannot tell the trajectory format: {n} values per line (TUM has 8, KITTI 12)",
                     path=path, line=numbers[0])


def read_trajectory(path: str | Path, fmt: TrajectoryFormat = "auto",
                    times_path: str | Path | None = None) -> Trajectory:
    """Read a trajectory in ``fmt`` (``"auto"``: :func:`detect_format`); ``times_path`` is for KITTI."""
    kind = detect_format(path) if fmt == "auto" else fmt
    if kind == "tum":
        return read_tum(path)
    if kind == "kitti":
        return read_kitti(path, times_path)
    if kind == "euroc":
        return read_euroc_csv(path)
    raise InputError(f"unknown trajectory format {fmt!r}: use tum, kitti, euroc or auto")


def _format_rows(mat: NDArray[np.float64]) -> str:
    return "".join(" ".join(map(repr, row)) + "\n" for row in mat.tolist())


def write_tum(path: str | Path, traj: Trajectory, header: bool = True) -> Path:
    """Write ``traj`` as a TUM file atomically (with a ``#`` header line unless ``header=False``)."""
    mat = np.column_stack([traj.timestamps, traj.positions, traj.quaternions_xyzw()])
    text = ("# timestamp tx ty tz qx qy qz qw\n" if header else "") + _format_rows(mat)
    return write_text(path, text)


def write_kitti(path: str | Path, traj: Trajectory, times_path: str | Path | None = None) -> Path:
    """Write ``traj`` as a KITTI pose file atomically; the times too if ``times_path`` is given."""
    write_text(path, _format_rows(traj.poses[:, :3, :].reshape(-1, 12)))
    if times_path is not None:
        write_text(times_path, _format_rows(traj.timestamps.reshape(-1, 1)))
    return Path(path)


def write_trajectory(path: str | Path, traj: Trajectory, fmt: Literal["tum", "kitti"] = "tum") -> Path:
    """Write ``traj`` as ``"tum"`` or ``"kitti"``."""
    if fmt == "tum":
        return write_tum(path, traj)
    if fmt == "kitti":
        return write_kitti(path, traj)
    raise InputError(f"unknown trajectory format {fmt!r} for writing: use tum or kitti")
