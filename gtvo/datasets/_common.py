"""Helpers shared by the dataset readers: checked paths, text tables, lazy image loaders,
pose conversions and the association of ground truth to image timestamps.

Everything here raises :class:`gtvo.errors.InputError` with a one-line message naming the file
(and line) for bad input.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.errors import InputError, not_a_file
from gtvo.core.paths import link_problem
from gtvo.core.lie import QUATERNION_NORM_TOLERANCE
from gtvo.core.image import to_float_gray
from gtvo.core.native_output import captured_native_stderr

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# paths and text tables

def require_dir(path: Path, what: str = "folder") -> Path:
    """``path`` if it is a directory, else InputError naming it."""
    if not path.exists():
        broken = link_problem(path)
        raise InputError(f"{what} is {broken}" if broken else f"{what} not found", path=path)
    if not path.is_dir():
        raise InputError(f"{what} is not a folder", path=path)
    return path


def require_file(path: Path, what: str = "file") -> Path:
    """``path`` if it is a regular file, else InputError naming it."""
    if not path.is_file():
        raise not_a_file(path, what)
    return path


@dataclass(frozen=True)
class TextRow:
    """One data line of a text table: its 1-based line number and its fields."""

    line: int
    fields: list[str]


def read_rows(path: Path, min_fields: int, delimiter: str | None = None) -> list[TextRow]:
    """Data lines of a text table; blank lines and ``#`` comments are skipped.

    Args:
        path: the file.
        min_fields: a row with fewer fields raises InputError naming ``path:line``.
        delimiter: ``","`` for csv, None for whitespace.
    """
    require_file(path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read text file ({exc.__class__.__name__})", path=path) from None
    rows = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f.strip() for f in line.split(delimiter)] if delimiter else line.split()
        if len(fields) < min_fields:
            raise InputError(f"expected at least {min_fields} fields, got {len(fields)}", path=path, line=number)
        rows.append(TextRow(number, fields))
    return rows


def parse_floats(row: TextRow, path: Path, columns: slice | None = None) -> FloatArray:
    """The fields of ``row`` (or a slice of them) as finite floats, else InputError at path:line."""
    fields = row.fields if columns is None else row.fields[columns]
    try:
        values = np.array([float(f) for f in fields], dtype=np.float64)
    except ValueError:
        bad = next(f for f in fields if not _is_float(f))
        raise InputError(f"not a number: {bad!r}", path=path, line=row.line) from None
    if not np.all(np.isfinite(values)):
        raise InputError("NaN or infinite value", path=path, line=row.line)
    return values


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def parse_float_table(rows: list[TextRow], path: Path, columns: slice) -> FloatArray:
    """``(len(rows), k)`` finite floats from the given columns of every row."""
    return np.array([parse_floats(r, path, columns) for r in rows], dtype=np.float64).reshape(len(rows), -1)


def parse_timestamp_ns(text: str, path: Path, line: int) -> int:
    """An integer nanosecond timestamp (EuRoC), else InputError at path:line."""
    try:
        return int(text)
    except ValueError:
        raise InputError(f"not an integer nanosecond timestamp: {text!r}", path=path, line=line) from None


# --------------------------------------------------------------------------------------------
# images

def read_image(path: Path) -> NDArray:
    """The raw image at ``path`` (any depth, channels as stored), InputError when unreadable."""
    if not path.is_file():
        raise not_a_file(path, "image file")
    with captured_native_stderr() as native:  # libpng & co. print their own complaints: kept out of the console
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    # a decoder error with an image returned all the same: the image is partial or garbage
    if image is None or image.size == 0 or any("error" in line.lower() for line in native.lines()):
        said = f": {native.summary()}" if native.lines() else ""
        raise InputError(f"cannot read image (unreadable or corrupt file{said})", path=path)
    return image


def image_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` of the image at ``path``."""
    image = read_image(path)
    return int(image.shape[1]), int(image.shape[0])


def check_image_shape(image: NDArray, shape: tuple[int, int], path: Path, what: str) -> None:
    """InputError naming ``path`` when ``image`` is not ``shape`` = (height, width)."""
    if image.shape[:2] != tuple(shape):
        raise InputError(f"{what} image is {image.shape[1]}x{image.shape[0]}, expected "
                         f"{shape[1]}x{shape[0]} like the other images (mismatched size)", path=path)


class GrayImageLoader:
    """Lazily loads image ``i`` of a list of files as float32 gray (:func:`gtvo.core.image.to_float_gray`)."""

    def __init__(self, paths: list[Path], shape: tuple[int, int], what: str):
        self.paths = list(paths)
        self.shape = shape
        self.what = what

    def __call__(self, i: int) -> NDArray[np.float32]:
        path = self.paths[i]
        image = read_image(path)
        check_image_shape(image, self.shape, path, self.what)
        try:
            return to_float_gray(image, name=f"{self.what} image")
        except InputError as exc:
            raise InputError(str(exc), path=path) from None


class DepthImageLoader:
    """Lazily loads a 16-bit depth png as metres (``value / scale``, 0 = no measurement)."""

    def __init__(self, paths: list[Path], shape: tuple[int, int], scale: float):
        self.paths = list(paths)
        self.shape = shape
        self.scale = float(scale)

    def __call__(self, i: int) -> NDArray[np.float32]:
        path = self.paths[i]
        image = read_image(path)
        if image.ndim != 2 or image.dtype != np.uint16:
            raise InputError(f"depth image must be 16-bit single-channel, got {image.dtype} with shape "
                             f"{image.shape}", path=path)
        check_image_shape(image, self.shape, path, "depth")
        return image.astype(np.float32) / np.float32(self.scale)


# --------------------------------------------------------------------------------------------
# poses and association

def poses_from_quaternions(translations: ArrayLike, quats_xyzw: ArrayLike, path: Path,
                           lines: list[int]) -> FloatArray:
    """(N, 4, 4) poses from translations (N, 3) and quaternions (N, 4) in ``x y z w`` order.

    A quaternion whose norm is not within :data:`gtvo.core.lie.QUATERNION_NORM_TOLERANCE`
    of 1 raises InputError at ``path:line`` (as the trajectory readers do); the rest are normalised.
    """
    t = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(quats_xyzw, dtype=np.float64).reshape(-1, 4)
    norms = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if bad.size:
        k = int(bad[0])
        raise InputError(f"quaternion is not unit length (norm {norms[k]:.6g})", path=path, line=lines[k])
    from scipy.spatial.transform import Rotation  # noqa: PLC0415 - scipy.spatial: 0.3 s of a run's start

    poses = np.tile(np.eye(4), (t.shape[0], 1, 1))
    poses[:, :3, :3] = Rotation.from_quat(q / norms[:, None]).as_matrix()
    poses[:, :3, 3] = t
    return poses


def nearest_indices(reference: FloatArray, query: FloatArray) -> tuple[NDArray[np.intp], FloatArray]:
    """For each query time, the index of the nearest reference time and the absolute difference.

    ``reference`` must be sorted ascending.
    """
    reference = np.asarray(reference, dtype=np.float64)
    query = np.asarray(query, dtype=np.float64)
    right = np.clip(np.searchsorted(reference, query), 1, reference.size - 1) if reference.size > 1 else \
        np.zeros(query.shape, dtype=np.intp)
    left = np.maximum(right - 1, 0)
    d_left = np.abs(query - reference[left])
    d_right = np.abs(query - reference[right])
    pick = np.where(d_right < d_left, right, left)
    return pick, np.minimum(d_left, d_right)


def associate_unique(reference: FloatArray, query: FloatArray, tolerance: float
                     ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Pairs ``(query_index, reference_index)`` of nearest times within ``tolerance``, each
    reference used at most once (the closest query keeps it), like TUM's ``associate.py``.
    """
    ref_idx, diff = nearest_indices(reference, query)
    ok = np.flatnonzero(diff <= tolerance)
    # Among queries sharing a reference, keep the closest one.
    order = np.lexsort((diff[ok], ref_idx[ok]))
    ok = ok[order]
    first = np.ones(ok.size, dtype=bool)
    first[1:] = ref_idx[ok][1:] != ref_idx[ok][:-1]
    kept = np.sort(ok[first])
    return kept, ref_idx[kept]


def interpolate_poses(gt_times: FloatArray, gt_poses: FloatArray, query_times: FloatArray,
                      tolerance: float, max_gap: float) -> FloatArray:
    """Ground-truth poses at ``query_times``: (M, 4, 4), NaN where none is close enough.

    A query strictly between two samples at most ``max_gap`` apart is interpolated (linear
    translation, rotation ``R_i Exp(a Log(R_i^T R_j))``, i.e. slerp). Otherwise the nearest sample
    is used when it is within ``tolerance``; otherwise the row is NaN.
    """
    gt_times = np.asarray(gt_times, dtype=np.float64)
    query = np.asarray(query_times, dtype=np.float64)
    out = np.full((query.size, 4, 4), np.nan)
    if gt_times.size == 0:
        return out
    near, diff = nearest_indices(gt_times, query)
    use_near = diff <= tolerance
    out[use_near] = gt_poses[near[use_near]]
    if gt_times.size > 1:
        j = np.searchsorted(gt_times, query, side="right")
        inside = (j > 0) & (j < gt_times.size)
        i0 = np.clip(j - 1, 0, gt_times.size - 2)
        i1 = i0 + 1
        gap = gt_times[i1] - gt_times[i0]
        interp = inside & (gap <= max_gap) & (gap > 0)
        if np.any(interp):
            from scipy.spatial.transform import Rotation  # noqa: PLC0415 - as above

            a, b = i0[interp], i1[interp]
            alpha = (query[interp] - gt_times[a]) / (gt_times[b] - gt_times[a])
            r_a = Rotation.from_matrix(gt_poses[a, :3, :3])
            r_b = Rotation.from_matrix(gt_poses[b, :3, :3])
            delta = (r_a.inv() * r_b).as_rotvec()
            poses = np.tile(np.eye(4), (a.size, 1, 1))
            poses[:, :3, :3] = (r_a * Rotation.from_rotvec(alpha[:, None] * delta)).as_matrix()
            poses[:, :3, 3] = (1 - alpha[:, None]) * gt_poses[a, :3, 3] + alpha[:, None] * gt_poses[b, :3, 3]
            out[interp] = poses
    return out


def require_overlap(poses: FloatArray, gt_path: Path, image_times: FloatArray, gt_times: FloatArray) -> None:
    """InputError when no frame received a ground-truth pose."""
    if poses.shape[0] and not np.any(np.isfinite(poses[:, 0, 0])):
        raise InputError(f"ground truth ({gt_times[0]:.3f}..{gt_times[-1]:.3f} s) does not overlap the images "
                         f"in time ({image_times[0]:.3f}..{image_times[-1]:.3f} s)", path=gt_path)


def read_tum_trajectory(path: Path) -> tuple[FloatArray, FloatArray]:
    """``(times (N,), T_world_x (N, 4, 4))`` from a TUM file ``t tx ty tz qx qy qz qw``."""
    rows = read_rows(path, 8)
    if not rows:
        raise InputError("trajectory file has no poses", path=path)
    table = parse_float_table(rows, path, slice(0, 8))
    return _sorted_trajectory(table[:, 0], poses_from_quaternions(table[:, 1:4], table[:, 4:8], path,
                                                                  [r.line for r in rows]), path)


def read_asl_trajectory(path: Path) -> tuple[FloatArray, FloatArray]:
    """``(times (N,) in s, T_world_body (N, 4, 4))`` from an ASL csv ``ns, px, py, pz, qw, qx, qy, qz, ...``."""
    rows = read_rows(path, 8, delimiter=",")
    if not rows:
        raise InputError("ground-truth csv has no rows", path=path)
    ns = np.array([parse_timestamp_ns(r.fields[0], path, r.line) for r in rows], dtype=np.int64)
    table = parse_float_table(rows, path, slice(1, 8))
    quats_xyzw = table[:, [4, 5, 6, 3]]
    return _sorted_trajectory(ns * 1e-9, poses_from_quaternions(table[:, 0:3], quats_xyzw, path,
                                                              [r.line for r in rows]), path)


def _sorted_trajectory(times: FloatArray, poses: FloatArray, path: Path) -> tuple[FloatArray, FloatArray]:
    order = np.argsort(times, kind="stable")
    times, poses = times[order], poses[order]
    if times.size > 1 and np.any(np.diff(times) <= 0):
        raise InputError("ground truth has repeated timestamps", path=path)
    return times, poses


def read_trajectory(path: Path) -> tuple[FloatArray, FloatArray]:
    """A ground-truth trajectory in ASL csv (comma separated, ns) or TUM (whitespace, s) form."""
    require_file(path, "ground-truth file")
    with path.open("r", encoding="utf-8", errors="replace") as f:
        first = next((line for line in f if line.strip() and not line.lstrip().startswith("#")), None)
    if first is None:
        raise InputError("ground-truth file is empty", path=path)
    return read_asl_trajectory(path) if "," in first else read_tum_trajectory(path)
