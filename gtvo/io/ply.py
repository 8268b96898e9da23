"""Points with grey levels as a binary PLY, written with numpy.

The file holds one ``vertex`` element, ``x y z`` as little-endian doubles and ``red green blue``
as bytes (the grey level three times), what open3d wrote before and reads
(:func:`gtvo.planning.occupancy.read_point_cloud`). No native library is involved: a write that
fails (a full disk, a file-size limit) is one ``OSError`` naming the file, with nothing printed
(open3d's PLY writer printed a line per failed write first), and the file is written atomically
(:func:`gtvo.core.atomic.atomic_open`): a failed write leaves no partial file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from gtvo.errors import InputError
from gtvo.core.atomic import atomic_open

#: The vertex record: position (m) and colour.
VERTEX = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])


def grey_levels(intensity: ArrayLike) -> np.ndarray:
    """Bytes of intensities (0..255): clipped, then truncated as open3d turned a colour in [0, 1]
    into a byte (``uint8(min(255, max(0, c 255)))``, ``c = intensity / 255``)."""
    c = np.clip(np.asarray(intensity, dtype=np.float64).reshape(-1) / 255.0, 0.0, 1.0)
    return np.clip(c * 255.0, 0.0, 255.0).astype(np.uint8)


def ply_header(count: int) -> bytes:
    """The header of a file of ``count`` vertices (:data:`VERTEX`)."""
    lines = ["ply", "format binary_little_endian 1.0", "comment written by gtvo", f"element vertex {count}",
             *(f"property {'double' if VERTEX[name].kind == 'f' else 'uchar'} {name}" for name in VERTEX.names),
             "end_header"]
    return ("\n".join(lines) + "\n").encode("ascii")


def write_ply_points(path: str | Path, points: ArrayLike, intensity: ArrayLike) -> Path:
    """Write points (N, 3) with grey colours from intensities (N,) (0..255) as a binary PLY at
    ``path``, atomically; raises ``OSError`` when the system refuses the write."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    grey = grey_levels(intensity)
    if grey.size != len(pts):
        raise InputError(f"{len(pts)} points but {grey.size} intensities", path=path)
    vertices = np.empty(len(pts), dtype=VERTEX)
    vertices["x"], vertices["y"], vertices["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    vertices["red"] = vertices["green"] = vertices["blue"] = grey
    with atomic_open(path, "wb") as f:
        f.write(ply_header(len(pts)))
        f.write(vertices.tobytes())
    return Path(path)


def read_ply_points(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(points (N, 3), grey (N,))`` of a file :func:`write_ply_points` wrote (for tests and
    checks; :func:`gtvo.planning.occupancy.read_point_cloud` reads any point cloud)."""
    data = Path(path).read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise InputError("not a PLY file", path=path)
    header = data[:end].decode("ascii", errors="replace").splitlines()
    count = next((int(line.split()[2]) for line in header if line.startswith("element vertex ")), -1)
    body = data[end + len(b"end_header\n"):]
    if ply_header(count) != data[:end + len(b"end_header\n")] or len(body) != count * VERTEX.itemsize:
        raise InputError("not a PLY file of gtvo's points (header or size differs)", path=path)
    vertices = np.frombuffer(body, dtype=VERTEX)
    return np.column_stack([vertices["x"], vertices["y"], vertices["z"]]), vertices["red"].copy()
