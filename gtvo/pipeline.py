"""The whole job on one sequence: read -> track -> outputs. Used by ``gtvo run``, ``gtvo demo``
and by Python users (:func:`run`).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from contextlib import nullcontext
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from gtvo import __version__
from gtvo.core.atomic import ensure_output_dir, tidy_on_failure
from gtvo.datasets import detect_format, open_sequence
from gtvo.core.interrupt import raise_if_interrupted
from gtvo.core.timing import stage
from gtvo.errors import InputError
from gtvo.config import OdometryConfig, as_config, config_to_yaml
from gtvo.io.observer import RunObserver
from gtvo.odometry import VisualOdometry
from gtvo.odometry.estimates import FrameOutcome, trust_warning
from gtvo.io.covariances import KeyframeCovariances
from gtvo.odometry.rig_report import rig_warning
from gtvo.odometry.summary import OdometrySummary, stage_timing, summarize_odometry
from gtvo.odometry.imu import gravity_alignment
from gtvo.odometry.wheel import wheel_coverage_warning
from gtvo.io.outputs import check_run_output_dir, write_run_outputs
from gtvo.datasets.sequence import Sequence
from gtvo.evaluation.trajectory import Trajectory
from gtvo.report import RunReport, run_report


#: Outcomes whose pose comes from tracking (the others are keyframes or predictions): the frames
#: that ``--loop-closure`` re-estimates against the final keyframes.
TRACKED_OUTCOMES = (FrameOutcome.TRACKED, FrameOutcome.RECOVERED)

#: ``covariances.npz``'s source when the whole-log refinement was kept (its graph's marginals).
REFINED_COVARIANCES = {"gtsam": "gtsam.Marginals of the whole-log refinement's graph",
                       "handrolled": "inverse of the whole-log refinement's reduced Hessian (hand-rolled)"}


def process_sequence(seq: Sequence, config: OdometryConfig | None = None, progress: bool = False,
                     strict: bool = False, warn: Callable[[str], None] | None = None,
                     observers: Iterable[RunObserver] = (),
                     ) -> tuple[VisualOdometry, Trajectory, OdometrySummary]:
    """Run the odometry over ``seq``.

    A frame whose images cannot be read is skipped with a warning (and counted), unless
    ``strict``; the first frame must be readable, since everything starts from it.
    ``observers`` (:class:`gtvo.io.observer.RunObserver`, e.g. the Rerun logger) see the start,
    every processed frame and the end.

    Returns:
        ``(vo, trajectory, summary)``: the odometry's summary
        (:func:`gtvo.odometry.summary.summarize_odometry`: frames, keyframes, seconds, frames per
        second, failures, skipped frames, ``frame_outcomes``, window and rig figures, timing).
    """
    config = config or OdometryConfig()
    coverage = None if seq.wheel_odometry is None else wheel_coverage_warning(seq.wheel_odometry, seq.timestamps)
    vo = VisualOdometry(seq.camera, config, wheel_odometry=seq.wheel_odometry, imu=seq.imu)
    try:  # a parallel window's worker ends here, however the run ends (its figures are in the summary)
        observers = list(observers)
        for o in observers:
            o.on_start(seq, config)
        warn = warn or (lambda msg: print(f"warning: {msg}", file=sys.stderr))
        skipped: list[tuple[int, str]] = []
        bar = None
        indices: Any = range(len(seq))
        if progress:
            from tqdm import tqdm  # noqa: PLC0415

            bar = tqdm(indices, desc=f"gtvo {seq.name}", unit="frame", dynamic_ncols=True, file=sys.stderr)
            indices = bar
        t0 = time.perf_counter()
        for i in indices:
            raise_if_interrupted()  # a Ctrl-C that a library swallowed stops the run here
            # the loop's time outside vo.process (observers, progress bar) is the stage "other"
            with vo.clock.activate("other") if vo.clock is not None else nullcontext():
                try:
                    with stage("reading"):
                        frame = seq.frame(i)
                except InputError as exc:
                    if strict or not vo.estimates:
                        raise
                    skipped.append((i, str(exc)))
                    warn(f"skipping frame {i}: {exc}")
                    continue
                estimate = vo.process(frame)
                if observers:
                    view = vo.view()
                    for o in observers:
                        o.on_frame(frame, estimate, view)
                if bar is not None:
                    bar.set_postfix(kf=len(vo.keyframes), fail=vo.failures,
                                    **({"win": len(vo.window_results)} if config.mode == "window" else {}))
        vo.finish()  # the keyframes that joined the window since its last optimisation
        seconds = time.perf_counter() - t0
        traj = vo.trajectory(seq.name)
        info = summarize_odometry(vo, seconds, skipped)
    finally:
        vo.close()
    wheel = info.get("wheel_calibration")
    for message in (rig_warning(dict(info)), trust_warning(info["frames"], info["undetermined_frames"],
                                                           info["trusted_fraction"]),
                    coverage, None if wheel is None else wheel["warning"]):
        if message is not None:
            warn(message)
    if observers:
        view = vo.view()
        for o in observers:
            o.on_finish(view, traj, info)
    return vo, traj, info


def run(path: str | Path | Sequence, out: str | Path | None = None,
        config: OdometryConfig | dict[str, Any] | str | Path | None = None,
        format: str = "auto", max_frames: int | None = None, progress: bool = False,
        strict: bool = False, loop_closure: bool = False, frame_step: int = 1,
        observers: Iterable[RunObserver] = (), **open_options: Any) -> RunReport:
    """Run gtvo on a sequence folder (or an opened :class:`Sequence`) and write its outputs.

    Args:
        path: a KITTI / EuRoC / TUM folder, a ROS bag, or a :class:`Sequence`.
        out: output folder (``gtvo_out/<sequence name>`` when None).
        config: odometry settings: an :class:`OdometryConfig`, a partial tree as a dict, or a
            YAML/JSON file (:func:`gtvo.config.as_config`; default the defaults, as ``gtvo run``'s); recorded
            in full in the report (``"config"``) and in ``out/config.yaml``.
        format, max_frames, open_options: passed to :func:`gtvo.datasets.open_sequence` (for bags
            also ``calib``, ``left_topic``, ``right_topic``, ``depth_topic``, ``ground_truth_topic``;
            ``wheel_odometry``, ``wheel_topic``; ``imu``, ``imu_topic``), with the config's ``wheel:``
            and ``imu:`` sections as ``wheel_options`` and ``imu_options``.
        progress: show a progress bar.
        strict: stop at the first unreadable frame instead of skipping it.
        loop_closure: True sets ``loops.enabled`` of the config (as ``--loop-closure``; False leaves
            the config's): after the run, detect loops among the keyframes, optimise the keyframe
            pose graph robustly (GNC), re-estimate every tracked frame against the final keyframes
            and write ``trajectory_loop_closed.tum`` as a second output (:mod:`gtvo.loops.closing`);
            ``points.ply`` then holds the map on the loop-closed keyframe poses.
        frame_step: use every ``frame_step``-th frame (after ``max_frames``): the log at a lower
            frame rate (:meth:`Sequence.subsampled`).
        observers: see the run as it goes (:func:`process_sequence`), e.g.
            :class:`gtvo.io.rerun_log.RerunLogger`.

    Returns:
        The report (:class:`gtvo.report.RunReport`, also written to ``out/report.json``), with
        ``"out"`` added. Besides the run's figures it records ``"config"`` (the whole resolved
        tree, :func:`gtvo.config.config_to_dict`; ``gtvo run --config`` reads it back),
        ``"gtvo_version"`` and ``"input"`` (:func:`gtvo.datasets.identity.sequence_identity`).

    Raises:
        InputError: bad input (unreadable folder, ``frame_step < 1``, ...).
    """
    config = as_config(config)
    seq = path if isinstance(path, Sequence) else open_sequence(  # type: ignore[arg-type]
        path, format=format, max_frames=max_frames,
        **{"wheel_options": config.wheel.read_options(), "imu_options": config.imu.read_options(), **open_options})
    out_dir = Path(out) if out is not None else Path("gtvo_out") / seq.name
    check_run_output_dir(out_dir, seq)  # before the long work
    unpaired = seq.unpaired_warning() if hasattr(seq, "unpaired_warning") else None  # a bag's dropped images
    if unpaired is not None:
        print(f"warning: {unpaired}", file=sys.stderr)
    if isinstance(path, Sequence) and max_frames is not None:
        seq = seq.truncated(max_frames)
    seq = seq.subsampled(frame_step)
    if loop_closure:
        config = dataclasses.replace(config, loops=dataclasses.replace(config.loops, enabled=True))
    fmt = None if isinstance(path, Sequence) else (detect_format(path) if format == "auto" else format)
    with tidy_on_failure():  # a run that fails leaves no empty output folder behind
        ensure_output_dir(out_dir)  # an unusable --out is reported before the long work
        vo, traj, summary = process_sequence(seq, config, progress=progress, strict=strict, observers=observers)
        closed = closed_keyframes = loops = res = refined = None
        refining = bool(getattr(vo.window, "retain_keyframes", False))  # refine.enabled, sequential window mode
        if config.loops.enabled:
            from gtvo.loops.closing import close_loops_of_run, odometry_covariances  # noqa: PLC0415

            keyframes = [p for p, e in enumerate(vo.estimates) if e.is_keyframe]
            res = close_loops_of_run(seq, traj, [e.index for e in vo.estimates], keyframes, progress=progress,
                                     odometry_covariances=odometry_covariances(vo.estimates, keyframes),
                                     keyframe_points={kf.index: kf.points for kf in vo.keyframes},
                                     tracking_config=vo.config.tracking, refine_frames=not refining,
                                     refine=[e.outcome in TRACKED_OUTCOMES for e in vo.estimates],
                                     detector_config=config.loops.detector, photometric=config.photometric)
        if refining:  # the whole-log refinement (gtvo.refinement; its frames re-placed, or the loop closing's)
            refined = refine_vo_run(seq, vo, traj, res, progress)
            traj = refined.trajectory
        if res is not None:
            closed, closed_keyframes, loops = res.trajectory, res.keyframe_poses, res.summary()
        raise_if_interrupted()
        with vo.clock.activate() if vo.clock is not None else nullcontext(), stage("outputs", absorb=True):
            covariances = keyframe_covariances(vo)
            if covariances is not None and refined is not None and refined.covariances is not None:
                covariances = dataclasses.replace(covariances, source=REFINED_COVARIANCES[vo.config.refine.solver])
            alignment = gravity_alignment(vo)  # with an IMU: the outputs in the gravity-aligned world (docs/imu.md)
            if alignment is not None:
                traj, closed = alignment.trajectory(traj), alignment.trajectory(closed)
            info = run_report(seq, traj, summary, config, format=fmt, frame_step=frame_step, loop_closure=loops,
                              loop_closed=closed, covariances=covariances,
                              refinement=None if refined is None else refined.summary)
            if refined is not None and closed_keyframes is None and refined.keyframe_poses:
                closed_keyframes = refined.keyframe_poses  # the map on the refined keyframes
            points = vo.map_points(closed_keyframes)
            report = write_run_outputs(out_dir, traj, seq, info,
                                       points=points if alignment is None else alignment.points(points),
                                       loop_closed=closed, covariances=covariances,
                                       config_yaml=config_to_yaml(config, f"gtvo {__version__}: gtvo run --config this file"),
                                       stage_figures=lambda: stage_timing(vo))
    report["out"] = str(out_dir)
    return report  # type: ignore[return-value]


def refine_vo_run(seq: Sequence, vo: VisualOdometry, trajectory: Trajectory, loop_result: Any,
                  progress: bool) -> Any:
    """The whole-log refinement of a finished window run (:func:`gtvo.refinement.run.refine_run`;
    ``loop_result``: the loop closing's, before its frame refinement, or None). When it is kept,
    the keyframes' points take its depths and the window's covariances its graph's (the map and
    ``covariances.npz`` come from the refined graph). Returns its :class:`RunRefinement`."""
    from gtvo.loops.closing import odometry_covariances  # noqa: PLC0415
    from gtvo.refinement.run import refine_run  # noqa: PLC0415

    assert vo.window is not None
    keyframes = [p for p, e in enumerate(vo.estimates) if e.is_keyframe]
    rig = vo.window.rig
    refined = refine_run(seq, trajectory, [e.index for e in vo.estimates], keyframes, vo.window.every_keyframe(),
                         vo.config.window, vo.config.refine, photometric=vo.config.photometric,
                         tracking=vo.config.tracking, rig_offset=None if rig is None else rig.solved_offset,
                         keyframe_points={kf.index: kf.points for kf in vo.keyframes},
                         odometry_covariances=odometry_covariances(vo.estimates, keyframes),
                         refine=[e.outcome in TRACKED_OUTCOMES for e in vo.estimates], loop_result=loop_result,
                         progress=progress, warn=lambda msg: print(f"warning: {msg}", file=sys.stderr),
                         wheel=getattr(vo.window, "wheel", None))
    for kf in vo.keyframes:
        if kf.index in refined.inverse_depths:
            kf.points = dataclasses.replace(kf.points, inverse_depth=refined.inverse_depths[kf.index])
    if refined.covariances is not None:
        vo.window.covariances.update(refined.covariances)
    return refined


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
