"""A cheap identity of a run's input, for ``report.json`` (which frames a trajectory came from).

:func:`sequence_identity` hashes (SHA-256) what tells two inputs apart without reading every
image: the frame count, the timestamps, each frame's name (the left image's path relative to the
sequence folder) and file size, and the bytes of the first and last left images (their decoded
pixels for a generated sequence). Renaming, adding, dropping, re-timing or re-encoding a frame,
or editing the first or last image changes it, and so does the wheel odometry when the sequence has
some (its kind, times and readings); copying the folder elsewhere does not (names are relative,
modification times are not used). An edit to an inner image that keeps its file size
goes unnoticed: the price of not reading every image.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

import numpy as np

from gtvo.datasets.sequence import Sequence
from gtvo.errors import InputError


def sequence_identity(seq: Sequence, format: str | None = None) -> dict[str, Any]:
    """``{"path", "format", "kind", "frames", "first_frame", "last_frame", "sha256"}`` of ``seq``
    (module doc); ``path`` is absolute (as given, made absolute: a link is not followed);
    ``format`` is the layout it was read as (None for an in-memory sequence)."""
    h = hashlib.sha256()
    h.update(f"{seq.kind}:{len(seq)}\n".encode())
    h.update(np.ascontiguousarray(seq.timestamps, dtype="<f8").tobytes())
    names = [_relative(n, seq.source) for n in seq.frame_names]
    for name, full in zip(names, seq.frame_names):
        h.update(f"{name}\t{_size(full)}\n".encode())
    for i in sorted({0, len(seq) - 1}):
        h.update(_content(seq, i))
    wheels = seq.wheel_odometry
    if wheels is not None:  # nothing hashed without: the identity of a log without wheels is as it was
        h.update(f"wheels:{wheels.kind}:{len(wheels)}\n".encode())
        h.update(np.ascontiguousarray(np.column_stack([wheels.times, wheels.values]), dtype="<f8").tobytes())
    imu = seq.imu
    if imu is not None:  # likewise: a log without an IMU (or run with --no-imu) keeps its identity
        h.update(f"imu:{len(imu)}\n".encode())
        h.update(np.ascontiguousarray(np.column_stack([imu.times, imu.gyro, imu.accel]), dtype="<f8").tobytes())
        h.update(np.ascontiguousarray(imu.T_cam_imu, dtype="<f8").tobytes())
    return {"path": None if seq.source is None else os.path.abspath(seq.source), "format": format, "kind": seq.kind,
            "frames": len(seq), "first_frame": names[0], "last_frame": names[-1], "sha256": h.hexdigest()}


def _relative(name: str, root: Path | None) -> str:
    if root is None:
        return name
    try:
        return Path(name).resolve().relative_to(Path(root).resolve()).as_posix()
    except (ValueError, OSError, RuntimeError):  # (RuntimeError: a symbolic link loop, a frame skipped)
        return name


def _size(name: str) -> int:
    try:
        return os.stat(name).st_size
    except OSError:
        return -1


def _content(seq: Sequence, i: int) -> bytes:
    """The bytes of frame ``i``'s left image file, or its pixels when it is no file."""
    name = seq.frame_names[i]
    if os.path.isfile(name):
        with open(name, "rb") as fh:
            return fh.read()
    try:
        return np.ascontiguousarray(seq.left(i), dtype="<f4").tobytes()
    except InputError:  # an unreadable frame: the run skips it; its name is hashed already
        return b""
