"""TUM RGB-D layout: colour + registered depth with mocap ground truth.

::

    <seq>/rgb.txt           "timestamp filename" per colour image (rgb/<t>.png)
    <seq>/depth.txt         "timestamp filename" per depth image (16-bit png, metres = value / 5000)
    <seq>/groundtruth.txt   optional "timestamp tx ty tz qx qy qz qw", T_world_cam at ~100 Hz

Colour and depth are associated by nearest timestamp within :data:`ASSOCIATION_TOLERANCE_S`,
each depth image used once (TUM's ``associate.py``); colour images without depth are dropped.
The folders carry no intrinsics: the published pinhole values of fr1/fr2/fr3 are picked from
the folder name (``...freiburg3...`` -> fr3) unless a camera is passed.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from gtvo.core.camera import PinholeCamera
from gtvo.datasets._common import (DepthImageLoader, FloatArray, GrayImageLoader, associate_unique, image_size,
                                   interpolate_poses, parse_floats, read_rows, read_tum_trajectory, require_dir,
                                   require_overlap)
from gtvo.errors import InputError, show
from gtvo.datasets.sequence import Sequence

#: Colour/depth (and ground-truth nearest) association tolerance, as TUM's associate.py.
ASSOCIATION_TOLERANCE_S = 0.02
#: Ground truth is interpolated between samples at most this far apart (s).
GT_MAX_GAP_S = 0.1
#: Depth png units per metre.
DEPTH_SCALE = 5000.0
#: The image size TUM's published intrinsics are for (width, height).
TUM_IMAGE_SIZE = (640, 480)
#: TUM's published intrinsics (fx, fy, cx, cy) of the colour cameras, 640x480.
TUM_INTRINSICS: dict[str, tuple[float, float, float, float]] = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3),
    "freiburg2": (520.9, 521.0, 325.1, 249.7),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
}


def looks_like_tum(path: Path) -> bool:
    """True when ``path`` has rgb.txt and depth.txt."""
    return (path / "rgb.txt").is_file() and (path / "depth.txt").is_file()


def intrinsics_for(folder: Path, camera: tuple[float, float, float, float] | None
                   ) -> tuple[float, float, float, float]:
    """``camera`` when given, else TUM's published values for the ``freiburgN`` in the folder name."""
    if camera is not None:
        try:
            values = tuple(float(v) for v in camera)
        except (TypeError, ValueError):
            values = ()
        if len(values) != 4 or not all(np.isfinite(values)) or values[0] <= 0 or values[1] <= 0:
            raise InputError(f"camera must be four finite numbers fx fy cx cy with fx, fy > 0, got {show(camera)}")
        return values  # type: ignore[return-value]
    match = re.search(r"freiburg([123])", folder.resolve().name)
    if match is None:
        raise InputError("TUM folder carries no intrinsics and its name names no freiburg1/2/3 camera: "
                         "pass --camera FX,FY,CX,CY", path=folder)
    return TUM_INTRINSICS[f"freiburg{match.group(1)}"]


def _read_list(path: Path) -> tuple[FloatArray, list[Path]]:
    rows = read_rows(path, 2)
    times = np.array([parse_floats(r, path, slice(0, 1))[0] for r in rows], dtype=np.float64)
    return times, [path.parent / r.fields[1] for r in rows]


def read_tum(root: Path, max_frames: int | None = None, camera: tuple[float, float, float, float] | None = None,
             ground_truth: Path | None = None) -> Sequence:
    """Open a TUM RGB-D sequence folder as an RGB-D sequence (colour converted to gray).

    Args:
        root: the sequence folder.
        max_frames: keep only the first associated frames.
        camera: ``(fx, fy, cx, cy)`` overriding the intrinsics picked from the folder name.
        ground_truth: a TUM trajectory to use instead of ``root/groundtruth.txt``.
    """
    require_dir(root, "TUM sequence folder")
    fx, fy, cx, cy = intrinsics_for(root, camera)
    rgb_times, rgbs = _read_list(root / "rgb.txt")
    depth_times, depths = _read_list(root / "depth.txt")
    if rgb_times.size == 0:
        raise InputError("empty sequence: no images", path=root / "rgb.txt")
    if depth_times.size == 0:
        raise InputError("empty sequence: no depth images", path=root / "depth.txt")
    order = np.argsort(depth_times, kind="stable")
    rgb_idx, depth_idx = associate_unique(depth_times[order], rgb_times, ASSOCIATION_TOLERANCE_S)
    if rgb_idx.size == 0:
        raise InputError(f"no colour image has a depth image within {ASSOCIATION_TOLERANCE_S} s",
                         path=root / "depth.txt")
    if max_frames is not None:
        rgb_idx, depth_idx = rgb_idx[:max_frames], depth_idx[:max_frames]
    times = rgb_times[rgb_idx]
    rgb_paths = [rgbs[k] for k in rgb_idx]
    depth_paths = [depths[int(order[k])] for k in depth_idx]
    for path in rgb_paths + depth_paths:
        if not path.is_file():
            raise InputError("image listed in rgb.txt/depth.txt not found", path=path)

    gt_path = ground_truth if ground_truth is not None else root / "groundtruth.txt"
    gt_poses = None
    if ground_truth is not None or gt_path.exists():
        gt_times, T_world_cam = read_tum_trajectory(gt_path)
        gt_poses = interpolate_poses(gt_times, T_world_cam, times, ASSOCIATION_TOLERANCE_S, GT_MAX_GAP_S)
        require_overlap(gt_poses, gt_path, times, gt_times)

    width, height = image_size(rgb_paths[0])
    if camera is None and (width, height) != TUM_IMAGE_SIZE:
        raise InputError(f"the image is {width}x{height} but TUM's published intrinsics are for "
                         f"{TUM_IMAGE_SIZE[0]}x{TUM_IMAGE_SIZE[1]}: pass --camera FX,FY,CX,CY", path=rgb_paths[0])
    shape = (height, width)
    try:
        pinhole = PinholeCamera(fx, fy, cx, cy, width, height)
    except InputError as exc:  # the cause named first: the --camera value, else the published values for this image
        if camera is not None:
            raise InputError(f"--camera {show(camera)}: {exc}") from None
        raise InputError(f"TUM's published intrinsics: {exc}", path=rgb_paths[0]) from None
    return Sequence(
        name=root.resolve().name, kind="rgbd", camera=pinhole,
        timestamps=times, load_left=GrayImageLoader(rgb_paths, shape, "colour"),
        load_depth=DepthImageLoader(depth_paths, shape, DEPTH_SCALE), gt_poses=gt_poses, source=root,
        frame_names=[str(p) for p in rgb_paths])
