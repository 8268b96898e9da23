"""A run's report: :class:`RunReport`, what ``gtvo run`` writes as ``report.json``, built in one
place (:func:`run_report`) from the odometry's summary, the evaluation and the loop closing.

``report.json`` is this dictionary as JSON, key for key (docs/evaluation.md, "report.json",
documents every key). :func:`gtvo.run` returns it; the batch (:mod:`gtvo.batching`) and the
console summary of ``gtvo run`` / ``gtvo demo`` read their figures from it, never from the run's
other files. :func:`read_report` reads one back.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, TypedDict

from gtvo import __version__
from gtvo.config import OdometryConfig, config_to_dict
from gtvo.datasets.identity import sequence_identity
from gtvo.datasets.sequence import Sequence
from gtvo.errors import InputError
from gtvo.evaluation.accuracy import LoopClosedMetrics, TrajectoryMetrics, loop_closed_accuracy, run_accuracy
from gtvo.evaluation.trajectory import Trajectory
from gtvo.io.covariances import CovarianceSummary, KeyframeCovariances, covariance_summary
from gtvo.io.outputs import MapPointsFigures
from gtvo.loops.closing import LoopClosureSummary
from gtvo.odometry.summary import OdometrySummary
from gtvo.refinement.run import RefinementSummary


class RunExtras(TypedDict, total=False):
    """The keys of :class:`RunReport` that only some runs have."""

    unpaired_messages: dict[str, int]  # a ROS bag: per image topic, the messages that found no partner
    refine: RefinementSummary  # the whole-log refinement (refine.enabled): what ran, or why not
    out: str  # the output folder: in what gtvo.run returns, not in report.json


class RunReport(OdometrySummary, LoopClosureSummary, TrajectoryMetrics, LoopClosedMetrics, CovarianceSummary,
                MapPointsFigures, RunExtras):
    """A run's report: the keys of ``report.json`` (docs/evaluation.md, "report.json").

    In file order: ``sequence`` and ``source``; the odometry's figures (:class:`OdometrySummary`);
    the run's identity (``frame_step``, ``gtvo_version``, ``input``, ``config`` and, for a ROS
    bag, ``unpaired_messages``); with ``--loop-closure`` the loop closing's
    (:class:`gtvo.loops.closing.LoopClosureSummary`); the metrics against ground truth
    (:class:`gtvo.evaluation.accuracy.TrajectoryMetrics`; ``ground_truth`` False without) and
    the loop-closed trajectory's (``loop_closed_*``); the covariances' summary
    (:class:`gtvo.io.covariances.CovarianceSummary`); the map's counts
    (:class:`gtvo.io.outputs.MapPointsFigures`). :func:`gtvo.run` adds ``out`` (the output
    folder), which ``report.json`` does not hold.
    """

    sequence: str
    source: str | None
    frame_step: int
    gtvo_version: str
    input: dict[str, Any]
    config: dict[str, Any]


#: The report's headline figures, in the order the console summary of ``gtvo run`` prints them.
HEADLINE_FIELDS: tuple[str, ...] = (
    "frames", "keyframes", "seconds", "frames_per_second", "tracking_failures", "flow_recoveries", "lost_frames",
    "suspect_frames", "trusted_fraction", "window_optimisations", "window_seconds_mean", "ate_rmse_m", "ate_sim3_rmse_m", "scale_ratio",
    "rig_offset_px", "rig_offset_sigma_px", "rpe_trans_rmse_m", "ate_skipped", "drift_percent", "loops_detected",
    "loops_accepted", "frames_refined", "loop_closed_ate_rmse_m", "loop_closed_drift_percent", "map_points_written",
    "map_points_left_out", "unpaired_messages")


def run_report(seq: Sequence, estimate: Trajectory, odometry: OdometrySummary, config: OdometryConfig, *,
               format: str | None = None, frame_step: int = 1, loop_closure: LoopClosureSummary | None = None,
               loop_closed: Trajectory | None = None,
               covariances: KeyframeCovariances | None = None,
               refinement: RefinementSummary | None = None) -> RunReport:
    """The report of a run of ``seq`` (everything but the map's counts, which the writer adds:
    :func:`gtvo.io.outputs.write_run_outputs`).

    Args:
        seq: the sequence the run read (name, source, ground truth, identity).
        estimate: the run's trajectory, evaluated against the ground truth.
        odometry: the odometry's summary (:func:`gtvo.odometry.summary.summarize_odometry`).
        config: the run's resolved settings, recorded whole.
        format: the input's format as given or detected (None: a :class:`Sequence` given directly).
        frame_step: the run used every ``frame_step``-th frame.
        loop_closure: with ``--loop-closure``, what it found
            (:meth:`gtvo.loops.closing.LoopClosingResult.summary`), and ``loop_closed`` its trajectory.
        covariances: the keyframes' covariances written beside the report, summarised.
        refinement: the whole-log refinement's ``refine`` block (:mod:`gtvo.refinement.run`), when
            ``refine.enabled``.
    """
    report: dict[str, Any] = {"sequence": seq.name, "source": None if seq.source is None else str(seq.source)}
    report.update(odometry)
    report.update(frame_step=int(frame_step), gtvo_version=__version__, input=sequence_identity(seq, format),
                  config=config_to_dict(config))
    if getattr(seq, "unpaired", None) is not None:  # a ROS bag: messages that found no partner
        report["unpaired_messages"] = seq.unpaired  # type: ignore[attr-defined]
    if loop_closure is not None:
        report.update(loop_closure)
    if refinement is not None:
        report["refine"] = dict(refinement)
    report.update(run_accuracy(seq, estimate))
    if loop_closed is not None:
        report.update(loop_closed_accuracy(seq, loop_closed))
    if covariances is not None:
        report.update(covariance_summary(covariances))  # its "covariances" replaces the odometry's
    return report  # type: ignore[return-value]  # built key by key in report order


def headline(report: RunReport) -> list[tuple[str, Any]]:
    """The report's :data:`HEADLINE_FIELDS` that it holds and that are not None, with their values."""
    return [(k, report[k]) for k in HEADLINE_FIELDS if report.get(k) is not None]  # type: ignore[literal-required]


def read_report(path: str | Path) -> RunReport:
    """A run's ``report.json`` read back, or a one-line :class:`InputError` naming the file."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read the run report ({exc.__class__.__name__})", path=path) from None
    if not isinstance(data, dict):
        raise InputError("the run report is not a JSON object", path=path)
    return data  # type: ignore[return-value]
