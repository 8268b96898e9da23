"""KITTI odometry layout: rectified stereo pairs with a ``calib.txt`` of projection matrices.

::

    <seq>/calib.txt                 P0 and P1 (3x4 row-major), labelled "P0:"/"P1:" or not;
                                    P2, P3 for the colour pair; further lines (Tr, ...) ignored
    <seq>/image_0/*.png, image_1/   left/right (or image_l/, image_r/), same file names; without
                                    them, the colour pair image_2/, image_3/ (read as gray)
    <seq>/times.txt                 optional, one time [s] per image (else 0.1 s steps)
    <seq>/poses.txt                 optional ground truth, 3x4 row-major T_world_cam0 per image;
                                    without it, the KITTI odometry release's own place for it,
                                    <dataset>/poses/<seq name>.txt beside <dataset>/sequences/<seq>

Each rectified camera i is cam0 moved by ``t_i = K^-1 P_i[:, 3]`` (``X_i = X_0 + t_i``), so
``baseline = (t_left - t_right)_x`` (``= -P1[0,3]/P1[0,0]`` for the gray pair, where ``t_0 = 0``),
and ground truth, given for cam0, is carried to the left camera: ``T_world_left =
T_world_cam0 [I | -t_left]``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.datasets._common import (FloatArray, GrayImageLoader, TextRow, image_size, parse_floats,
                                   parse_float_table, read_rows, require_dir, require_file)
from gtvo.errors import InputError
from gtvo.datasets.sequence import Sequence
from gtvo.core.lie import ROTATION_TOLERANCE, rotation_block_error, rotation_defects

#: (left, right) image folder names tried in order, with the projection matrices of their cameras.
IMAGE_DIRS: tuple[tuple[str, str, str, str], ...] = (("image_0", "image_1", "P0", "P1"),
                                                     ("image_l", "image_r", "P0", "P1"),
                                                     ("image_2", "image_3", "P2", "P3"))
#: Frame period used when there is no times.txt (KITTI runs at 10 Hz).
DEFAULT_PERIOD_S = 0.1
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".ppm", ".bmp", ".tif", ".tiff")


def looks_like_kitti(path: Path) -> bool:
    """True when ``path`` has a calib.txt and a left image folder."""
    return (path / "calib.txt").is_file() and any((path / d[0]).is_dir() for d in IMAGE_DIRS)


def rectified_pair(path: Path, cameras: tuple[str, str]) -> tuple[FloatArray, float, FloatArray]:
    """``(K, baseline, t_left)``: ``t_left`` is the left camera's offset from cam0 (module docstring)."""
    PL, PR = read_projections(path, cameras)
    return rectified_from_projections(PL, PR, cameras, path)


def rectified_from_projections(PL: FloatArray, PR: FloatArray, cameras: tuple[str, str],
                               path: Path | str) -> tuple[FloatArray, float, FloatArray]:
    """``(K, baseline, t_left)`` of a rectified pair from its 3x4 projections ``PL, PR`` (named
    ``cameras`` in errors, which name ``path``); also used for ROS ``CameraInfo.P``."""
    left, right = cameras
    fx = PL[0, 0]
    if not fx > 0 or not PL[1, 1] > 0:
        raise InputError(f"{left} has non-positive focal length fx={float(fx)!r}, fy={float(PL[1, 1])!r}", path=path)
    if not np.allclose(PL[:, :3], PR[:, :3], rtol=1e-6, atol=1e-6 * fx):
        raise InputError(f"{left} and {right} have different intrinsics: images are not rectified", path=path)
    K = PL[:, :3].copy()
    if not (K[2, 0] == 0 and K[2, 1] == 0 and K[2, 2] > 0):
        raise InputError(f"{left}'s last row must be (0, 0, >0, .), got {PL[2].tolist()}", path=path)
    t_left, t_right = np.linalg.solve(K, PL[:, 3]), np.linalg.solve(K, PR[:, 3])
    baseline = t_left[0] - t_right[0]
    if not baseline > 0:
        raise InputError(f"baseline (K^-1 {left}[:,3] - K^-1 {right}[:,3])_x = {float(baseline):.6g} must be "
                         f"positive", path=path)
    return K, float(baseline), t_left


def read_projections(path: Path, cameras: tuple[str, str] = ("P0", "P1")) -> tuple[FloatArray, FloatArray]:
    """The 3x4 projection matrices ``cameras`` (e.g. ``("P0", "P1")``) from ``calib.txt``: the
    labelled lines ``P0: ...``, or in a file without labels the lines in P0, P1, P2, P3 order."""
    rows = read_rows(require_file(path, "calibration file"), 1)
    if not rows:
        raise InputError(f"empty calibration file: no {' or '.join(cameras)} line", path=path)
    labelled = {r.fields[0].rstrip(":"): r for r in rows if r.fields[0].endswith(":")}
    if not labelled and not all(re.fullmatch(r"P\d", k) for k in cameras):  # (only P0..P3 come unlabelled)
        raise InputError(f"no {' or '.join(cameras)} line (no line is labelled 'NAME:')", path=path)
    if labelled:
        missing = [k for k in cameras if k not in labelled]
        if missing:
            raise InputError(f"no {' or '.join(missing)} line", path=path)
        picked = [TextRow(labelled[k].line, labelled[k].fields[1:]) for k in cameras]
    else:
        order = [int(k[1:]) for k in cameras]
        if len(rows) <= max(order):
            raise InputError(f"expected {' and '.join(cameras)} lines (P0, P1, P2, P3 in order), found "
                             f"{len(rows)} line(s)", path=path)
        picked = [rows[k] for k in order]
    matrices = []
    for row in picked:
        if len(row.fields) != 12:
            raise InputError(f"projection matrix needs 12 numbers, got {len(row.fields)}", path=path, line=row.line)
        matrices.append(parse_floats(row, path).reshape(3, 4))
    return matrices[0], matrices[1]


def _image_dirs(root: Path) -> tuple[Path, Path, tuple[str, str]]:
    for left, right, p_left, p_right in IMAGE_DIRS:
        if (root / left).is_dir():
            return root / left, require_dir(root / right, "right image folder"), (p_left, p_right)
    raise InputError(f"no left image folder ({', '.join(d[0] for d in IMAGE_DIRS)})", path=root)


def _read_poses(path: Path, count: int) -> FloatArray:
    rows = read_rows(path, 12)
    if len(rows) != count:
        raise InputError(f"{len(rows)} poses for {count} images: {path.name} needs one line per image", path=path)
    for row in rows:
        if len(row.fields) != 12:
            raise InputError(f"pose needs 12 numbers, got {len(row.fields)}", path=path, line=row.line)
    table = parse_float_table(rows, path, slice(0, 12))
    poses = np.tile(np.eye(4), (count, 1, 1))
    poses[:, :3, :] = table.reshape(count, 3, 4)
    ortho, det = rotation_defects(poses[:, :3, :3])
    bad = np.flatnonzero((ortho > ROTATION_TOLERANCE) | (det <= 0))
    if bad.size:
        k = int(bad[0])
        raise InputError(f"rotation block {rotation_block_error(poses[k, :3, :3])}", path=path, line=rows[k].line)
    return poses


def _read_times(path: Path, count: int) -> FloatArray:
    rows = read_rows(path, 1)
    if len(rows) != count:
        raise InputError(f"{len(rows)} timestamps for {count} images: times.txt needs one line per image",
                         path=path)
    for row in rows:
        if len(row.fields) != 1:
            raise InputError(f"expected one timestamp per line, got {len(row.fields)} fields", path=path,
                             line=row.line)
    times = parse_float_table(rows, path, slice(0, 1)).reshape(-1)
    back = np.flatnonzero(np.diff(times) <= 0)
    if back.size:
        raise InputError(f"timestamps are not strictly increasing ({times[back[0]]:.9g} then "
                         f"{times[back[0] + 1]:.9g})", path=path, line=rows[back[0] + 1].line)
    return times


def default_ground_truth(root: Path) -> Path | None:
    """``root/poses.txt``, else ``<dataset>/poses/<name>.txt`` when ``root`` is
    ``<dataset>/sequences/<name>`` (the KITTI odometry release's layout), else None."""
    inside = root / "poses.txt"
    if inside.exists():
        return inside
    for seq in (Path(os.path.abspath(root)), root.resolve()):  # as given (a link), then its target
        if seq.parent.name == "sequences":
            release = seq.parent.parent / "poses" / f"{seq.name}.txt"
            if release.is_file():
                return release
    return None


def read_kitti(root: Path, max_frames: int | None = None, ground_truth: Path | None = None) -> Sequence:
    """Open a KITTI odometry sequence folder (see the module docstring for the layout).

    Args:
        root: the sequence folder.
        max_frames: keep only the first frames.
        ground_truth: a KITTI poses file to use instead of the default
            (:func:`default_ground_truth`).
    """
    require_dir(root, "KITTI sequence folder")
    left_dir, right_dir, cameras = _image_dirs(root)
    K, baseline, t_left = rectified_pair(root / "calib.txt", cameras)
    lefts = sorted(p for p in left_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not lefts:
        raise InputError("empty sequence: no images", path=left_dir)
    rights = [right_dir / p.name for p in lefts]
    count = len(lefts)
    n = count if max_frames is None else min(count, int(max_frames))
    for left, right in zip(lefts[:n], rights[:n]):  # (frames past --max-frames are not read)
        if not right.is_file():
            raise InputError(f"missing right image for left image {left}", path=right)
    times_path = root / "times.txt"
    times = _read_times(times_path, count) if times_path.exists() else DEFAULT_PERIOD_S * np.arange(count)
    gt_path = ground_truth if ground_truth is not None else default_ground_truth(root)
    poses = _read_poses(gt_path, count) if gt_path is not None else None
    if poses is not None and np.any(t_left != 0):  # ground truth is cam0's: carry it to the left camera
        T_cam0_left = np.eye(4)
        T_cam0_left[:3, 3] = -t_left
        poses = poses @ T_cam0_left
    width, height = image_size(lefts[0])
    try:
        camera = StereoCamera(PinholeCamera.from_matrix(K, width, height), baseline)
    except InputError as exc:
        raise InputError(f"{exc} (from {cameras[0]})", path=root / "calib.txt") from None
    shape = (height, width)
    return Sequence(
        name=root.resolve().name, kind="stereo", camera=camera, timestamps=times[:n],
        load_left=GrayImageLoader(lefts[:n], shape, "left"), load_right=GrayImageLoader(rights[:n], shape, "right"),
        gt_poses=None if poses is None else poses[:n], source=root, frame_names=[str(p) for p in lefts[:n]])
