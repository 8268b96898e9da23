"""Outputs of a run: trajectory file, report, plots, point cloud (I/O at the edge).

:func:`evaluate` is pure (metrics against the sequence's ground truth); :func:`write_run_outputs`
writes ``trajectory.tum``, ``report.json``, ``trajectory.png`` (and ``errors.png``) and
``points.ply`` into one folder, replaced as a set.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from gtvo.io.atomic import atomic_dir, check_replaceable_dir, write_json
from gtvo.errors import DependencyError, InputError
from gtvo.evaluation.metrics import align_trajectory, ate, drift_percent, kitti_segment_errors, rpe
from gtvo.io.covariances import KeyframeCovariances, covariance_summary, position_ellipses, write_covariances
from gtvo.io.ply import write_ply_points
from gtvo.io.plots import CAMERA_WORLD_XZ_LABELS, plot_errors_over_time, plot_trajectory_top_view
from gtvo.datasets.sequence import Sequence
from gtvo.evaluation.trajectory import Trajectory
from gtvo.io.trajectory_files import write_tum
from gtvo.core.map_points import MapPoints


#: Below this ground-truth path length (m) no drift % and no segment metric are reported: on a
#: static clip they divide millimetres of noise by millimetres of path.
MIN_DRIFT_PATH_M = 0.1


def ground_truth(seq: Sequence, est: Trajectory) -> tuple[Trajectory, Trajectory] | None:
    """The (estimate, ground truth) pair restricted to frames that have ground truth, or None."""
    if not seq.has_ground_truth:
        return None
    assert seq.gt_poses is not None
    idx = np.searchsorted(seq.timestamps, est.timestamps)
    idx = np.clip(idx, 0, len(seq) - 1)
    gt = seq.gt_poses[idx]
    ok = np.isfinite(gt[:, 0, 0]) & np.isclose(seq.timestamps[idx], est.timestamps)
    if np.count_nonzero(ok) < 2:
        return None
    return est.subset(np.flatnonzero(ok)), Trajectory(est.timestamps[ok], gt[ok], name="ground truth")


def evaluate(est: Trajectory, ref: Trajectory) -> dict[str, Any]:
    """Metrics of an estimate against associated ground truth (same length, same times).

    ``ate_rmse_m``: SE(3)-aligned ATE (None, with the reason in ``ate_skipped``, when the
    alignment is not determined: fewer than 3 poses, or positions on a line or a point);
    ``ate_sim3_rmse_m``: Sim(3)-aligned ATE (the shape; with ``ate_rmse_m`` it tells a scale error from
    a shape error); ``scale_ratio``: estimated / ground-truth path length;
    ``rpe_trans_rmse_m`` / ``rpe_rot_rmse_deg``: frame-to-frame RPE; ``drift_percent``: final
    position error after aligning the first pose over the path length; ``kitti_*``: the devkit's
    segment metric on lengths that fit the path (None if none). When the ground-truth path is
    shorter than :data:`MIN_DRIFT_PATH_M`, ``drift_percent`` is None and the ``kitti_*`` keys are
    absent.
    """
    out: dict[str, Any] = {}
    try:
        a = ate(est, ref, "se3")
        out["ate_rmse_m"] = a.rmse
        out["ate_max_m"] = a.translation.max
        # Sim(3)-aligned ATE: the shape alone (a wrong scale does not count)
        out["ate_sim3_rmse_m"] = ate(est, ref, "sim3").rmse
    except InputError as exc:
        out["ate_rmse_m"] = out["ate_max_m"] = out["ate_sim3_rmse_m"] = None
        out["ate_skipped"] = str(exc)
    if len(est) >= 2:
        r = rpe(est, ref, 1, "frames")
        out["rpe_trans_rmse_m"] = r.translation.rmse
        out["rpe_rot_rmse_deg"] = r.rotation_deg.rmse
    length = ref.path_length()
    out["path_length_m"] = length
    # estimated / ground-truth path length: the scale (1 when the stereo baseline sets it right)
    out["scale_ratio"] = est.path_length() / length if length > 0 else None
    moves = length >= MIN_DRIFT_PATH_M
    out["drift_percent"] = drift_percent(est, ref) if moves else None
    if moves:
        lengths = [L for L in (100, 200, 300, 400, 500, 600, 700, 800) if L < length]
        if not lengths:  # short logs: segments of a quarter, half and three quarters of the path
            lengths = [round(length * f, 3) for f in (0.25, 0.5, 0.75)]
        k = kitti_segment_errors(est, ref, lengths=lengths, step=1)
        out["kitti_segment_lengths_m"] = list(lengths)
        out["kitti_translation_percent"] = None if k is None else k.translation_percent
        out["kitti_rotation_deg_per_100m"] = None if k is None else k.rotation_deg_per_100m
    return out


def write_point_cloud(path: str | Path, points: NDArray[np.float64], intensity: NDArray[np.float64]) -> Path:
    """Write points (N, 3) with gray colours from intensities (0..255) as a binary PLY
    (:func:`gtvo.io.ply.write_ply_points`: numpy, no open3d; a failed write is one OSError)."""
    return write_ply_points(path, points, intensity)


#: Every entry ``gtvo run`` writes into its output folder (an earlier run's set may be replaced).
RUN_OUTPUT_NAMES = frozenset({"trajectory.tum", "trajectory_loop_closed.tum", "report.json", "trajectory.png",
                              "errors.png", "points.ply", "covariances.npz", "config.yaml"})
#: Who writes run output folders (recorded in their :data:`gtvo.io.atomic.DIR_MARKER`).
RUN_WRITER = "gtvo run"


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
    """The folders a sequence is read from: ``(source folder, folders of its image files)``."""
    images: set[Path] = set()
    for loader in (seq.load_left, seq.load_right, seq.load_depth):
        images.update(Path(f).resolve().parent for f in getattr(loader, "paths", ()))
    images.update(Path(n).resolve().parent for n in seq.frame_names if Path(n).is_file())
    return (None if seq.source is None else Path(seq.source).resolve()), images


def check_run_output_dir(out_dir: str | Path, inputs: tuple[Path | None, set[Path]] | Sequence) -> Path:
    """The resolved ``out_dir`` if a run may write its outputs there, else a one-line :class:`InputError`.

    Refused: the input folder itself, an image folder of the input or a folder inside one
    (``inputs``: the sequence or its :func:`input_folders`), and a folder that is neither new,
    empty nor an earlier run's output set (:func:`gtvo.io.atomic.check_replaceable_dir`).
    """
    source, images = input_folders(inputs) if isinstance(inputs, Sequence) else inputs
    out = Path(out_dir).resolve()
    if source is not None and out == source:
        raise InputError("output folder is the input folder; outputs there would mix with the data: "
                         "choose another", path=out_dir)
    for f in sorted(images):
        if out == f or f in out.parents:
            where = "one of the input's image folders" if out == f else f"inside the input's image folder {f}"
            raise InputError(f"output folder is {where}; outputs there would mix with the frames: choose another",
                             path=out_dir)
    return check_replaceable_dir(out, RUN_OUTPUT_NAMES, RUN_WRITER)


def write_run_outputs(out_dir: str | Path, est: Trajectory, seq: Sequence, run_info: dict[str, Any],
                      points: MapPoints | tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
                      loop_closed: Trajectory | None = None,
                      covariances: KeyframeCovariances | None = None,
                      config_yaml: str | None = None,
                      stage_figures: Callable[[], dict[str, Any]] | None = None) -> dict[str, Any]:
    """Write a run's outputs into ``out_dir`` as a set and return the report written to ``report.json``.

    ``run_info`` holds the run's own figures (frames, keyframes, seconds, ...); metrics are added
    when the sequence has ground truth. ``points``: the map (:class:`gtvo.core.map_points.MapPoints`,
    whose counts go into the report as ``map_points_written`` / ``map_points_left_out``, or plain
    ``(points, intensities)``). ``loop_closed``, when given, is written as
    ``trajectory_loop_closed.tum`` and evaluated as ``loop_closed_*``. ``covariances``, when given,
    is written as ``covariances.npz``, summarised in the report and drawn as position ellipses in
    ``trajectory.png`` (:mod:`gtvo.io.covariances`). ``config_yaml``, when given, is written as
    ``config.yaml`` (the run's configuration, for ``gtvo run --config``). ``stage_figures``, when
    given, is called just before ``report.json`` is written and its keys go into the report (the
    run's timing by stage, with the outputs' own time so far: ``gtvo.pipeline.stage_report``).

    The files are written into a temporary folder beside ``out_dir`` that then replaces it
    (:func:`gtvo.io.atomic.atomic_dir`): an interrupted or failed write leaves the earlier set as
    it was, and no file of an earlier run is left beside the new ones. ``out_dir`` must be new,
    empty or an earlier run's output folder, and not the input's (:func:`check_run_output_dir`).
    """
    out_path = check_run_output_dir(out_dir, seq)
    report: dict[str, Any] = {"sequence": seq.name, "source": None if seq.source is None else str(seq.source)}
    report.update(run_info)
    # every figure first, then the files
    pair = ground_truth(seq, est)
    if pair is not None:
        est_gt, ref = pair
        report.update(evaluate(est_gt, ref))
        se3 = report["ate_rmse_m"] is not None
        aligned, _ = align_trajectory(est_gt, ref, "se3" if se3 else "origin")
        title = (f"{seq.name}: ATE {report['ate_rmse_m']:.3f} m (SE(3)-aligned)" if se3
                 else f"{seq.name} (first poses aligned)")
    else:
        report["ground_truth"] = False
    if loop_closed is not None:
        pair_lc = ground_truth(seq, loop_closed)
        if pair_lc is not None:
            m = evaluate(*pair_lc)
            report["loop_closed_ate_rmse_m"] = m["ate_rmse_m"]
            report["loop_closed_drift_percent"] = m["drift_percent"]
    if points is not None and not isinstance(points, MapPoints):
        points = MapPoints(np.asarray(points[0], dtype=float).reshape(-1, 3), np.asarray(points[1], dtype=float))
    if covariances is not None:
        report.update(covariance_summary(covariances))
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
            after = ("SE(3) alignment to the ground truth (least squares over all poses, as the ATE)" if se3
                     else "aligning the first poses")
            plot_errors_over_time(ref.timestamps, errs, out / "errors.png", title=f"{seq.name}: position error after "
                                  f"{after}", ylabel="position error after alignment [m]")
        else:
            plot_trajectory_top_view(est, None, out / "trajectory.png", title=f"{seq.name} (no ground truth)",
                                     ellipses=ellipses, **view)
        if loop_closed is not None:
            write_tum(out / "trajectory_loop_closed.tum", loop_closed)
        if points is not None:
            report["map_points_written"] = points.written
            report["map_points_left_out"] = points.left_out_total
            if points.left_out:
                report["map_points_left_out_by_reason"] = dict(points.left_out)
            if points.written:
                try:
                    write_point_cloud(out / "points.ply", points.points, points.intensity)
                except DependencyError as exc:
                    report["map_points_written"] = None
                    report["map_points_skipped"] = str(exc)
        if stage_figures is not None:
            report.update(stage_figures())
        write_json(out / "report.json", _jsonable(report))
    return report


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
