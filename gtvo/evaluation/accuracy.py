"""A run's accuracy against its sequence's ground truth: the metrics of ``report.json``.

:func:`ground_truth` pairs an estimate with the ground truth of the frames that have one;
:func:`evaluate` gives the metrics of such a pair (:class:`TrajectoryMetrics`);
:func:`run_accuracy` and :func:`loop_closed_accuracy` are the two a run's report holds (the
keys are documented in docs/evaluation.md, "report.json"). Pure math, no I/O.
"""

from __future__ import annotations

from typing import Protocol, TypedDict

import numpy as np
from numpy.typing import NDArray

from gtvo.errors import InputError
from gtvo.evaluation.metrics import ate, drift_percent, kitti_segment_errors, rpe
from gtvo.evaluation.trajectory import Trajectory

#: Below this ground-truth path length (m) no drift % and no segment metric are reported: on a
#: static clip they divide millimetres of noise by millimetres of path.
MIN_DRIFT_PATH_M = 0.1


class GroundTruthSource(Protocol):
    """What :func:`ground_truth` reads of a sequence (:class:`gtvo.datasets.sequence.Sequence` has it)."""

    @property
    def has_ground_truth(self) -> bool: ...

    @property
    def gt_poses(self) -> NDArray[np.float64] | None: ...

    @property
    def timestamps(self) -> NDArray[np.float64]: ...

    def __len__(self) -> int: ...


class TrajectoryMetrics(TypedDict, total=False):
    """The metrics of an estimate against its ground truth (:func:`evaluate`), as ``report.json``
    keys; a run without ground truth has only ``ground_truth`` = False (:func:`run_accuracy`)."""

    ground_truth: bool
    ate_rmse_m: float | None
    ate_max_m: float | None
    ate_sim3_rmse_m: float | None
    ate_skipped: str
    rpe_trans_rmse_m: float
    rpe_rot_rmse_deg: float
    path_length_m: float
    scale_ratio: float | None
    drift_percent: float | None
    kitti_segment_lengths_m: list[float]
    kitti_translation_percent: float | None
    kitti_rotation_deg_per_100m: float | None


class LoopClosedMetrics(TypedDict, total=False):
    """The loop-closed trajectory's ATE and drift (:func:`loop_closed_accuracy`)."""

    loop_closed_ate_rmse_m: float | None
    loop_closed_drift_percent: float | None


def ground_truth(seq: GroundTruthSource, est: Trajectory) -> tuple[Trajectory, Trajectory] | None:
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


def evaluate(est: Trajectory, ref: Trajectory) -> TrajectoryMetrics:
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
    out: TrajectoryMetrics = {}
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


def run_accuracy(seq: GroundTruthSource, est: Trajectory) -> TrajectoryMetrics:
    """A run's metrics (:func:`evaluate` on the frames with ground truth), or
    ``{"ground_truth": False}`` when fewer than two of its frames have ground truth."""
    pair = ground_truth(seq, est)
    return {"ground_truth": False} if pair is None else evaluate(*pair)


def loop_closed_accuracy(seq: GroundTruthSource, loop_closed: Trajectory) -> LoopClosedMetrics:
    """``loop_closed_ate_rmse_m`` and ``loop_closed_drift_percent`` of a loop-closed trajectory
    (:func:`evaluate`), or nothing without ground truth."""
    pair = ground_truth(seq, loop_closed)
    if pair is None:
        return {}
    m = evaluate(*pair)
    return {"loop_closed_ate_rmse_m": m["ate_rmse_m"], "loop_closed_drift_percent": m["drift_percent"]}
