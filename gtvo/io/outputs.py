"""Outputs of a run: trajectory file, report, plots, point cloud (I/O at the edge).

:func:`write_run_outputs` writes ``trajectory.tum``, ``report.json`` (the report it is given:
:func:`gtvo.report.run_report`), ``trajectory.png`` (and ``errors.png``) and ``points.ply`` into
one folder, replaced as a set. It computes no metric (those are :mod:`gtvo.evaluation`'s) and adds
nothing to the report: it writes the report as it is given.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
from numpy.typing import NDArray

from gtvo.core.atomic import atomic_dir, check_replaceable_dir, write_json
from gtvo.core.paths import identity, link_problem, resolved, same_or_inside
from gtvo.errors import InputError
from gtvo.evaluation.accuracy import ground_truth
from gtvo.evaluation.alignment import align_trajectory
from gtvo.io.covariances import KeyframeCovariances, position_ellipses, write_covariances
from gtvo.io.ply import write_ply_points
from gtvo.io.plots import CAMERA_WORLD_XZ_LABELS, load_in_background, plot_errors_over_time, plot_trajectory_top_view
from gtvo.datasets.sequence import Sequence
from gtvo.evaluation.trajectory import Trajectory
from gtvo.io.trajectory_files import write_tum
from gtvo.core.map_points import MapPoints


#: Every entry ``gtvo run`` writes into its output folder (an earlier run's set may be replaced).
RUN_OUTPUT_NAMES = frozenset({"trajectory.tum", "trajectory_loop_closed.tum", "report.json", "trajectory.png",
                              "errors.png", "points.ply", "covariances.npz", "config.yaml"})
#: Who writes run output folders (recorded in their :data:`gtvo.core.atomic.DIR_MARKER`).
RUN_WRITER = "gtvo run"


def load_plotting() -> None:
    """Start loading what :func:`write_run_outputs` plots with while the run goes
    (:func:`gtvo.io.plots.load_in_background`): its plots then do not wait for matplotlib's import."""
    load_in_background()


def top_view(ref: Trajectory | None) -> dict[str, Any]:
    """Plane and axis labels of a run's ``trajectory.png``.

    The estimate's world is the first camera (x right, y down, z forward), and an estimate aligned
    to ground truth is in the ground truth's world: when that is the first camera too (its first
    pose is the identity, as KITTI's), or there is no ground truth, the top view is the x-z plane
    named in that frame; otherwise the plot picks its plane (:func:`gtvo.io.plots.choose_plane`).
    """
    if ref is None or (len(ref) and np.allclose(ref.poses[0], np.eye(4), atol=1e-6)):
        return {"plane": "xz", "axis_labels": CAMERA_WORLD_XZ_LABELS}
    return {"plane": "auto"}


def input_folders(seq: Sequence) -> tuple[Path | None, set[Path]]:
    """The folders a sequence is read from: ``(source folder, folders of its image files)``.

    An image file's folder is the one it is listed in and, when it is a symbolic link, the one its
    target lies in too; a link that cannot be followed (a loop, a broken link: a frame the reader
    skips or stops at) gives only the former.
    """
    images: set[Path] = set()
    files = [Path(f) for loader in (seq.load_left, seq.load_right, seq.load_depth)
             for f in getattr(loader, "paths", ())]
    files += [Path(n) for n in seq.frame_names if link_problem(n) is None and Path(n).is_file()]
    for f in files:
        images.add(Path(os.path.abspath(f)).parent)
        if link_problem(f) is None:
            images.add(Path(os.path.realpath(f)).parent)
    source = None if seq.source is None else Path(os.path.abspath(seq.source))
    return source, images


def check_run_output_dir(out_dir: str | Path, inputs: tuple[Path | None, set[Path]] | Sequence) -> Path:
    """The resolved ``out_dir`` if a run may write its outputs there, else a one-line :class:`InputError`.

    Refused: the input folder itself or a folder inside it, an image folder of the input or a
    folder inside one (``inputs``: the sequence or its :func:`input_folders`), whatever the
    spelling (``..``, symbolic links, bind mounts: compared by file identity,
    :func:`gtvo.core.paths.same_or_inside`), a symbolic link loop, and a folder that is neither
    new, empty nor an earlier run's output set (:func:`gtvo.core.atomic.check_replaceable_dir`).
    """
    source, images = input_folders(inputs) if isinstance(inputs, Sequence) else inputs
    out = resolved(out_dir, "output folder")
    for f in sorted(images):
        if same_or_inside(out, f):
            where = ("one of the input's image folders" if identity(out) == identity(f)
                     else f"inside the input's image folder {f}")
            raise InputError(f"output folder is {where}; outputs there would mix with the frames: choose another",
                             path=out_dir)
    if source is not None and os.path.isdir(source) and same_or_inside(out, source):
        where = "the input folder" if identity(out) == identity(source) else f"inside the input folder {source}"
        raise InputError(f"output folder is {where}; outputs there would mix with the data: choose another",
                         path=out_dir)
    return check_replaceable_dir(out, RUN_OUTPUT_NAMES, RUN_WRITER)


def write_run_outputs(out_dir: str | Path, est: Trajectory, seq: Sequence,
                      report: Mapping[str, Any] | Callable[[], Mapping[str, Any]],
                      points: MapPoints | tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
                      loop_closed: Trajectory | None = None,
                      covariances: KeyframeCovariances | None = None,
                      config_yaml: str | None = None, metrics: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Write a run's outputs into ``out_dir`` as a set and return the report written to ``report.json``.

    ``report``: the run's report (:func:`gtvo.report.run_report`), written as it is; or the function
    that builds it, called once every other file is written (so that the report's timing of the
    outputs includes their writing). ``points`` (:class:`gtvo.core.map_points.MapPoints`, or plain
    ``(points, intensities)``), when given, are written as ``points.ply`` (when there are any).
    ``metrics``: the accuracy the plots state (its ``ate_rmse_m``; default the report's, when it is
    given as a mapping). ``loop_closed``, when given, is written as ``trajectory_loop_closed.tum``. ``covariances``,
    when given, is written as ``covariances.npz`` and drawn as position ellipses in
    ``trajectory.png`` (:mod:`gtvo.io.covariances`). ``config_yaml``, when given, is written as
    ``config.yaml`` (the run's configuration, for ``gtvo run --config``). With ground truth the
    plots show the estimate SE(3)-aligned to it when the metrics have an ``ate_rmse_m``, else with
    the first poses aligned.

    The files are written into a temporary folder beside ``out_dir`` that then replaces it
    (:func:`gtvo.core.atomic.atomic_dir`): an interrupted or failed write leaves the earlier set as
    it was, and no file of an earlier run is left beside the new ones. ``out_dir`` must be new,
    empty or an earlier run's output folder, and not the input's (:func:`check_run_output_dir`).
    """
    out_path = check_run_output_dir(out_dir, seq)
    pair = ground_truth(seq, est)
    if pair is not None:
        est_gt, ref = pair
        ate_m = (metrics if metrics is not None else report if not callable(report) else {}).get("ate_rmse_m")
        aligned, _ = align_trajectory(est_gt, ref, "se3" if ate_m is not None else "origin")
        title = (f"{seq.name}: ATE {ate_m:.3f} m (SE(3)-aligned)" if ate_m is not None
                 else f"{seq.name} (first poses aligned)")
    if points is not None and not isinstance(points, MapPoints):
        points = MapPoints(np.asarray(points[0], dtype=float).reshape(-1, 3), np.asarray(points[1], dtype=float))
    drawn = aligned if pair is not None else est
    ellipses = position_ellipses(covariances, drawn) if covariances is not None and len(covariances) else None
    view = top_view(None if pair is None else pair[1])
    with atomic_dir(out_path, RUN_OUTPUT_NAMES, RUN_WRITER) as out:
        write_tum(out / "trajectory.tum", est)
        if config_yaml is not None:
            (out / "config.yaml").write_text(config_yaml, encoding="utf-8")
        if covariances is not None and len(covariances):
            write_covariances(out / "covariances.npz", covariances)
        if pair is not None:
            plot_trajectory_top_view(aligned, ref, out / "trajectory.png", title=title, ellipses=ellipses, **view)
            errs = np.linalg.norm(aligned.positions - ref.positions, axis=1)
            after = ("SE(3) alignment to the ground truth (least squares over all poses, as the ATE)"
                     if ate_m is not None else "aligning the first poses")
            plot_errors_over_time(ref.timestamps, errs, out / "errors.png", title=f"{seq.name}: position error after "
                                  f"{after}", ylabel="position error after alignment [m]")
        else:
            plot_trajectory_top_view(est, None, out / "trajectory.png", title=f"{seq.name} (no ground truth)",
                                     ellipses=ellipses, **view)
        if loop_closed is not None:
            write_tum(out / "trajectory_loop_closed.tum", loop_closed)
        if points is not None and points.written:
            write_ply_points(out / "points.ply", points.points, points.intensity)  # numpy, no open3d: gtvo.io.ply
        written = dict(report() if callable(report) else report)
        write_json(out / "report.json", _jsonable(written))
    return written


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if np.isfinite(v) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj
