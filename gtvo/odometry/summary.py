"""What a finished odometry run says about itself: :class:`OdometrySummary`, made by
:func:`summarize_odometry` from the public members of :class:`VisualOdometry`.

The summary is the odometry's part of a run's ``report.json`` (:class:`gtvo.report.RunReport`),
under the same keys and in the same order; docs/evaluation.md ("report.json") documents each.
"""

from __future__ import annotations

import statistics
from typing import Any, Sequence, TypedDict

from gtvo.core.timing import per_frame_ms
from gtvo.odometry.estimates import frames_by_outcome, trusted_fraction, undetermined_frames
from gtvo.odometry.rig_report import rig_report
from gtvo.odometry.visual_odometry import VisualOdometry
from gtvo.odometry.imu import imu_report
from gtvo.odometry.wheel import wheel_report


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


def summarize_odometry(vo: VisualOdometry, seconds: float | None = None,
                       skipped: Sequence[tuple[int, str]] = ()) -> OdometrySummary:
    """The summary of a finished run of ``vo`` (call :meth:`VisualOdometry.finish` first).

    Args:
        vo: the odometry; only its public members are read.
        seconds: the run's wall time, measured by the caller around its loop over the frames
            (with the reading of the frames); None: ``frames_per_second`` is None too.
        skipped: ``(index, reason)`` of the frames the caller could not read (never given to ``vo``).
    """
    config = vo.config
    estimates = vo.estimates
    n = len(estimates)
    tracked = [e.tracking for e in estimates if e.tracking is not None and e.tracking.success and not e.suspect]
    sigmas = [t.rotation_sigma_deg for t in tracked]
    sigmas_t = [t.translation_sigma_m for t in tracked]
    out: dict[str, Any] = {
        "mode": config.mode,
        "tracker_solver": config.solver.tracker,
        "motion_model": config.motion_model.model,
        "frames": n,
        "keyframes": len(vo.keyframes),
        "seconds": seconds,
        "frames_per_second": n / seconds if seconds is not None and seconds > 0 else None,
        "tracking_failures": vo.failures,
        "reinitialisations": sum(1 for e in estimates if e.reinitialised),
        "flow_recoveries": vo.tracker.flow_recoveries,
        "lost_frames": vo.lost_frames,
        "suspect_frames": sum(1 for e in estimates if e.suspect),
        # the frames whose pose the run trusts, and those the images did not determine (docs/evaluation.md)
        "trusted_fraction": trusted_fraction(estimates),
        "undetermined_frames": undetermined_frames(estimates, config.tracking.max_relative_rms),
        "skipped_frames": [i for i, _ in skipped],
        # every flagged frame by index with its reason (docs/evaluation.md, "Frame outcomes")
        "frame_outcomes": frames_by_outcome(estimates, skipped),
        "tracking_iterations_mean": _mean([e.tracking.iterations for e in estimates if e.tracking is not None]),
        # how well the images determined each tracked frame's rotation (TrackingResult.rotation_sigma_deg)
        "tracking_rotation_sigma_deg_median": _median(sigmas),
        "tracking_rotation_sigma_deg_max": max(sigmas) if sigmas else None,
        # and its translation (TrackingResult.translation_sigma_m): in a dark log it grows with the error
        "tracking_translation_sigma_m_median": _median(sigmas_t),
        "tracking_translation_sigma_m_max": max(sigmas_t) if sigmas_t else None,
    }
    if config.mode == "window":
        window, results = vo.window, vo.window_results
        out.update({
            "window_backend": window.backend.name if window is not None else None,
            "window_solver": window.solver_name(config.solver.window) if window is not None else None,
            "window_size": config.window.size,
            "window_optimisations": len(results),
            "window_seconds_mean": _mean([r.seconds for r in results]),
            "window_iterations_mean": _mean([r.iterations for r in results]),
            "covariance_seconds": float(sum(r.covariance_seconds for r in results)),
        })
        out.update(rig_report(vo))
    out.update(wheel_report(vo.wheel, vo.window))
    out.update(imu_report(vo))
    out.update(stage_timing(vo))
    out.update(window_worker_figures(vo))
    out["covariances"] = ("not computed (--no-covariances)" if config.mode == "window" and not config.window.covariances
                          else "not computed (track mode: no window)" if config.mode != "window" else "computed")
    return out  # type: ignore[return-value]  # built key by key in report order


def stage_timing(vo: VisualOdometry) -> StageTiming:
    """``seconds_by_stage`` (the run's seconds in each stage of :data:`gtvo.core.timing.FRAME_STAGES`,
    an open stage's time so far included) and ``ms_per_frame_by_stage`` (the same per processed
    frame, ms); empty when the run was not timed (``vo.clock`` None) or processed no frame."""
    seconds = {} if vo.clock is None else vo.clock.snapshot()
    if not seconds or not vo.estimates:
        return {}
    return {"seconds_by_stage": seconds, "ms_per_frame_by_stage": per_frame_ms(seconds, len(vo.estimates))}


def window_worker_figures(vo: VisualOdometry) -> WindowWorkerFigures:
    """``window_worker`` (:class:`WindowWorkerFigures`) when the window runs in a worker process;
    empty otherwise. Asks the worker, so call it before the worker is closed."""
    worker = getattr(vo.keyframer, "worker", None)
    if worker is None:
        return {}
    usage = worker.usage()
    return {"window_worker": {"cpu_seconds": float(usage.cpu_seconds), "max_rss_mib": float(usage.max_rss_mib),
                              "seconds_by_stage": {k: float(v) for k, v in usage.seconds_by_stage.items()},
                              "kernel_threads": int(usage.kernel_threads),
                              "pool_cpu_seconds": float(usage.pool_cpu_seconds)}}


def _mean(xs: list[float]) -> float | None:
    return float(sum(xs) / len(xs)) if xs else None


def _median(xs: list[float]) -> float | None:
    return float(statistics.median(xs)) if xs else None
