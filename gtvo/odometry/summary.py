"""What a finished odometry run says about itself: :class:`gtvo.report.OdometrySummary`, made by
:func:`summarize_odometry` from the public members of :class:`VisualOdometry`.

The summary is the odometry's part of a run's ``report.json`` (:class:`gtvo.report.RunReport`,
whose module holds its type), under the same keys and in the same order; docs/evaluation.md
("report.json") documents each.
"""

from __future__ import annotations

import statistics
from typing import Any, Sequence

import numpy as np

from gtvo.core.timing import StageClock, per_frame_ms
from gtvo.evaluation.covariances import KeyframeCovariances
from gtvo.odometry.estimates import frames_by_outcome, trusted_fraction, undetermined_frames
from gtvo.odometry.result import MapKeyframe, OdometryResult, odometry_covariances
from gtvo.odometry.rig_report import rig_report
from gtvo.odometry.visual_odometry import VisualOdometry
from gtvo.odometry.imu import gravity_alignment, imu_report
from gtvo.odometry.wheel import wheel_report
from gtvo.report import OdometrySummary, StageTiming, WindowWorkerFigures

__all__ = ["OdometrySummary", "StageTiming", "WindowWorkerFigures", "clock_timing", "keyframe_covariances",
           "odometry_result", "stage_timing", "summarize_odometry", "window_worker_figures"]


def odometry_result(vo: VisualOdometry, seconds: float | None = None, skipped: Sequence[tuple[int, str]] = (),
                    name: str = "gtvo") -> OdometryResult:
    """What a finished run of ``vo`` hands on (:class:`gtvo.odometry.result.OdometryResult`), read once
    after :meth:`VisualOdometry.finish` and before :meth:`VisualOdometry.close`; ``seconds`` and
    ``skipped`` as :func:`summarize_odometry`'s, ``name`` the trajectory's (the sequence's)."""
    config, estimates = vo.config, tuple(vo.estimates)
    positions = [p for p, e in enumerate(estimates) if e.is_keyframe]
    window = vo.window
    retained = window is not None and window.retain_keyframes  # refine.enabled, window mode
    rig = None if window is None else window.rig
    return OdometryResult(
        config=config, pinhole=vo.pinhole, estimates=estimates, trajectory=vo.trajectory(name),
        summary=summarize_odometry(vo, seconds, skipped),
        keyframes=tuple(MapKeyframe(kf.index, kf.T_world_cam.matrix(), kf.points, vo.keyframer.observed(kf.index))
                        for kf in vo.keyframes),
        link_covariances=tuple(odometry_covariances(estimates, positions)),
        covariances=keyframe_covariances(vo),
        window_keyframes=tuple(window.every_keyframe()) if retained else None,  # type: ignore[union-attr]
        rig_offset=None if rig is None or not retained else rig.solved_offset,
        wheel=window.wheel if retained else None, imu=vo.imu if retained else None, clock=vo.clock,
        gravity_rotation=None if (aligned := gravity_alignment(vo)) is None else aligned.R_aligned_world)


def keyframe_covariances(vo: VisualOdometry, inflation: float = 1.0) -> KeyframeCovariances | None:
    """Every keyframe's pose covariance from its last window optimisation, times ``inflation``
    (:meth:`VisualOdometry.covariance`); None when the run computed none (track mode or
    ``WindowConfig.covariances=False``)."""
    if vo.window is None or not vo.config.window.covariances:
        return None
    stamp = {e.index: e.timestamp for e in vo.estimates}
    rows = [(kf.index, P) for kf in vo.keyframes if (P := vo.covariance(kf, inflation)) is not None]
    cw = vo.config.window
    source = ("iSAM2 marginalCovariance of the fixed-lag smoother" if cw.backend == "fixed_lag" else
              "gtsam.Marginals of the window's graph" if vo.config.solver.window == "gtsam" else
              "inverse of the window's reduced Hessian (hand-rolled)")
    return KeyframeCovariances(np.array([i for i, _ in rows], dtype=np.int64), np.array([stamp[i] for i, _ in rows]),
                               np.array([P for _, P in rows]).reshape(-1, 6, 6), source, float(inflation))


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
            "window_backend": window.backend_name if window is not None else None,
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
    return clock_timing(vo.clock, len(vo.estimates))


def clock_timing(clock: StageClock | None, frames: int) -> StageTiming:
    """:func:`stage_timing` of a run's ``clock`` over its ``frames`` processed frames."""
    seconds = {} if clock is None else clock.snapshot()
    if not seconds or not frames:
        return {}
    return {"seconds_by_stage": seconds, "ms_per_frame_by_stage": per_frame_ms(seconds, frames)}


def window_worker_figures(vo: VisualOdometry) -> WindowWorkerFigures:
    """``window_worker`` (:class:`WindowWorkerFigures`) when the window runs in a worker process;
    empty otherwise. Asks the worker, so call it before the worker is closed."""
    usage = None if vo.window is None else vo.window.worker_usage()
    if usage is None:
        return {}
    return {"window_worker": {"cpu_seconds": float(usage.cpu_seconds), "max_rss_mib": float(usage.max_rss_mib),
                              "seconds_by_stage": {k: float(v) for k, v in usage.seconds_by_stage.items()},
                              "kernel_threads": int(usage.kernel_threads),
                              "pool_cpu_seconds": float(usage.pool_cpu_seconds)}}


def _mean(xs: list[float]) -> float | None:
    return float(sum(xs) / len(xs)) if xs else None


def _median(xs: list[float]) -> float | None:
    return float(statistics.median(xs)) if xs else None
