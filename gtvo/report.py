"""A run's report: :class:`RunReport`, what ``gtvo run`` writes as ``report.json``, built in one
place (:func:`run_report`) from the run's result after its stages.

``report.json`` is this dictionary as JSON, key for key (docs/evaluation.md, "report.json",
documents every key). :func:`gtvo.run` returns it; the batch (:mod:`gtvo.batching`) and the
console summary of ``gtvo run`` / ``gtvo demo`` read their figures from it, never from the run's
other files. :func:`read_report` reads one back.

The report's types sit below the parts that fill them (evo's ``Result``, which knows no metric):
this module imports the settings, the readers' sequence and the evaluation, never the odometry,
loop closing, the refinement or the writers; they import their part's type from here
(:class:`OdometrySummary`, :class:`LoopClosureSummary`, :class:`RefinementSummary`), and the run's
result is read through :class:`RunResult`, the little of it a report needs.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Protocol, TypedDict

from gtvo import __version__
from gtvo.config import OdometryConfig, config_to_dict
from gtvo.core.map_points import MapPoints
from gtvo.datasets.identity import sequence_identity
from gtvo.datasets.sequence import Sequence
from gtvo.errors import InputError
from gtvo.evaluation.accuracy import LoopClosedMetrics, TrajectoryMetrics, loop_closed_accuracy, run_accuracy
from gtvo.evaluation.covariances import CovarianceSummary, KeyframeCovariances, covariance_summary
from gtvo.evaluation.trajectory import Trajectory


class StageTiming(TypedDict, total=False):
    """A run's time by stage (docs/evaluation.md, "Where a frame's time goes"); both keys absent
    when the run was not timed (``vo.clock`` None) or processed no frame."""

    seconds_by_stage: dict[str, float]
    ms_per_frame_by_stage: dict[str, float]


class WindowFigures(TypedDict, total=False):
    """The window's and the rig's figures of a run, present in window mode (the ``rig_offset_*``
    keys when the rig offset was estimated: :func:`gtvo.odometry.rig_report.rig_report`)."""

    window_backend: str | None
    window_solver: str | None
    window_size: int
    window_optimisations: int
    window_seconds_mean: float | None
    window_iterations_mean: float | None
    covariance_seconds: float
    rig_calibration: bool
    rig_offset_px: list[float]
    rig_offset_marginal_sigma_px: list[float | None] | None
    rig_offset_sigma_px: list[float | None] | None
    rig_offset_x_estimated: bool
    rig_offset_x_tested_px: float | None
    rig_initial_delta_y_px: float | None
    rig_offset_withheld: str | None


class WheelFigures(TypedDict, total=False):
    """The wheel odometry's calibration (:meth:`gtvo.window.wheel.WheelCalibration.report`), present
    when the run had wheel odometry."""

    wheel_calibration: dict[str, Any]


class ImuFigures(TypedDict, total=False):
    """The IMU's figures (:func:`gtvo.odometry.imu.imu_report`: gravity, biases, their sigmas, the
    output frame), present when the run had an IMU in the window."""

    imu: dict[str, Any]


class WindowWorkerFigures(TypedDict, total=False):
    """What the window's worker process spent (``window.parallel``): its CPU seconds (user +
    system), peak resident memory (MiB), wall seconds by stage of its own clock, its kernel
    threads and the CPU seconds its pool threads spent beside its main thread; present only
    when the window ran in a worker (the front end's ``seconds_by_stage`` then shows the wait)."""

    window_worker: dict[str, Any]


class OdometrySummary(StageTiming, WindowFigures, WheelFigures, ImuFigures, WindowWorkerFigures):
    """The odometry's figures of a run, in ``report.json`` order (:func:`summarize_odometry`).

    Always: what ran (``mode``, ``tracker_solver``, ``motion_model``), the counts, the frame
    outcomes, the tracking statistics and ``covariances`` (whether the keyframes' covariances were
    computed; the report replaces it by what was written). In window mode also the window's and
    the rig's figures (:func:`gtvo.odometry.rig_report.rig_report`). Then the stage timing.
    """

    mode: str
    tracker_solver: str
    motion_model: str
    frames: int
    keyframes: int
    seconds: float | None
    frames_per_second: float | None
    tracking_failures: int
    reinitialisations: int
    flow_recoveries: int
    lost_frames: int
    suspect_frames: int
    trusted_fraction: float | None
    undetermined_frames: list[int]
    skipped_frames: list[int]
    frame_outcomes: dict[str, Any]
    tracking_iterations_mean: float | None
    tracking_rotation_sigma_deg_median: float | None
    tracking_rotation_sigma_deg_max: float | None
    tracking_translation_sigma_m_median: float | None
    tracking_translation_sigma_m_max: float | None
    covariances: str


class LoopClosureSummary(TypedDict, total=False):
    """What loop closing found and did, as ``report.json`` keys (:meth:`gtvo.loops.closing.LoopClosingResult.summary`
    gives all six; not required keys because a run's report has them only with ``--loop-closure``)."""

    loops_detected: int
    loops_unrefined: int
    loops_accepted: int
    loop_closure_solver: str
    frames_refined: int
    frame_refinement_hosts_mean: float | None


class RefinementSummary(TypedDict, total=False):
    """The report's ``refine`` block (docs/evaluation.md, "report.json"; :func:`gtvo.refinement.run.run_refinement`)."""

    ran: bool
    reason: str | None
    solver: str
    keyframes: int
    targets_mean: float
    iterations: int
    cost_before: float | None
    cost_after: float | None
    seconds: float
    loop_edges: int
    loop_edges_dropped: int
    frames_replaced: int
    wheel_calibration: list[float]
    imu_factors: int
    window_ate_rmse_m: float | None
    window_ate_sim3_rmse_m: float | None
    window_scale_ratio: float | None


class MapPointsFigures(TypedDict, total=False):
    """The map's counts in ``report.json`` (:func:`map_points_figures` of the points written to
    ``points.ply``; docs/evaluation.md, "The map")."""

    map_points_written: int
    map_points_left_out: int
    map_points_left_out_by_reason: dict[str, int]


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
    (:class:`LoopClosureSummary`); with ``refine.enabled`` the refinement's ``refine`` block; the
    metrics against ground truth (:class:`gtvo.evaluation.accuracy.TrajectoryMetrics`;
    ``ground_truth`` False without) and the loop-closed trajectory's (``loop_closed_*``); the
    covariances' summary (:class:`gtvo.evaluation.covariances.CovarianceSummary`); the map's counts
    (:class:`MapPointsFigures`). :func:`gtvo.run` adds ``out`` (the output folder), which
    ``report.json`` does not hold.
    """

    sequence: str
    source: str | None
    frame_step: int
    gtvo_version: str
    input: dict[str, Any]
    config: dict[str, Any]


class RunMetrics(TrajectoryMetrics, LoopClosedMetrics):
    """A run's accuracy against the ground truth (:func:`run_metrics`): its trajectory's metrics and,
    with loop closing, the loop-closed trajectory's."""


class RunResult(Protocol):
    """What a report reads of a run's result (:class:`gtvo.odometry.result.OdometryResult` after the
    loop closing and the refinement)."""

    @property
    def config(self) -> OdometryConfig:
        """The run's resolved settings."""

    @property
    def trajectory(self) -> Trajectory:
        """The run's trajectory (``trajectory.tum``)."""

    @property
    def summary(self) -> OdometrySummary:
        """The odometry's figures."""

    @property
    def loop_closed(self) -> Trajectory | None:
        """The loop-closed trajectory, None without loop closing."""

    @property
    def loop_summary(self) -> LoopClosureSummary | None:
        """What loop closing found, None without it."""

    @property
    def refinement(self) -> RefinementSummary | None:
        """The refinement's ``refine`` block, None when it was not asked for."""

    @property
    def covariances(self) -> KeyframeCovariances | None:
        """The keyframes' pose covariances written beside the report, None when none were computed."""


#: The report's headline figures, in the order the console summary of ``gtvo run`` prints them.
HEADLINE_FIELDS: tuple[str, ...] = (
    "frames", "keyframes", "seconds", "frames_per_second", "tracking_failures", "flow_recoveries", "lost_frames",
    "suspect_frames", "trusted_fraction", "window_optimisations", "window_seconds_mean", "ate_rmse_m", "ate_sim3_rmse_m", "scale_ratio",
    "rig_offset_px", "rig_offset_sigma_px", "rpe_trans_rmse_m", "ate_skipped", "drift_percent", "loops_detected",
    "loops_accepted", "frames_refined", "loop_closed_ate_rmse_m", "loop_closed_drift_percent", "map_points_written",
    "map_points_left_out", "unpaired_messages")


def run_metrics(seq: Sequence, result: RunResult) -> RunMetrics:
    """The run's accuracy: its trajectory's metrics against ``seq``'s ground truth
    (:func:`gtvo.evaluation.accuracy.run_accuracy`) and the loop-closed trajectory's
    (:func:`gtvo.evaluation.accuracy.loop_closed_accuracy`), when there is one."""
    metrics: dict[str, Any] = dict(run_accuracy(seq, result.trajectory))
    if result.loop_closed is not None:
        metrics.update(loop_closed_accuracy(seq, result.loop_closed))
    return metrics  # type: ignore[return-value]


def run_report(seq: Sequence, result: RunResult, metrics: RunMetrics, *, format: str | None = None,
               frame_step: int = 1, points: MapPoints | None = None, timing: StageTiming | None = None) -> RunReport:
    """The report of a run of ``seq``: every key of ``report.json``, in its order.

    Args:
        seq: the sequence the run read (name, source, identity).
        result: the run's result after its stages: the odometry's summary, the loop closing's and
            the refinement's figures, the covariances (summarised), the settings (recorded whole).
        metrics: the run's accuracy (:func:`run_metrics`).
        format: the input's format as given or detected (None: a :class:`Sequence` given directly).
        frame_step: the run used every ``frame_step``-th frame.
        points: the map written to ``points.ply`` (its counts, :func:`map_points_figures`), if any.
        timing: the run's time by stage as of now (:func:`gtvo.odometry.summary.clock_timing`),
            replacing the odometry's (a run's outputs are timed up to the report).
    """
    report: dict[str, Any] = {"sequence": seq.name, "source": None if seq.source is None else str(seq.source)}
    report.update(result.summary)
    report.update(frame_step=int(frame_step), gtvo_version=__version__, input=sequence_identity(seq, format),
                  config=config_to_dict(result.config))
    if getattr(seq, "unpaired", None) is not None:  # a ROS bag: messages that found no partner
        report["unpaired_messages"] = seq.unpaired  # type: ignore[attr-defined]
    if result.loop_summary is not None:
        report.update(result.loop_summary)
    if result.refinement is not None:
        report["refine"] = dict(result.refinement)
    report.update(metrics)
    if result.covariances is not None:
        report.update(covariance_summary(result.covariances))  # its "covariances" replaces the odometry's
    if points is not None:
        report.update(map_points_figures(points))
    if timing:
        report.update(timing)  # the odometry's keys, their values as of now
    return report  # type: ignore[return-value]  # built key by key in report order


def map_points_figures(points: MapPoints) -> MapPointsFigures:
    """The map's counts: the points written to ``points.ply``, those left out and why."""
    figures: MapPointsFigures = {"map_points_written": points.written, "map_points_left_out": points.left_out_total}
    if points.left_out:
        figures["map_points_left_out_by_reason"] = dict(points.left_out)
    return figures


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
