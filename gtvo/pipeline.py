"""The whole job on one sequence, as its steps: read, odometry, loop closing, refinement, evaluate,
write. Used by ``gtvo run``, ``gtvo demo`` and by Python users (:func:`run`).

The odometry hands back one value (:class:`gtvo.odometry.result.OdometryResult`); loop closing
(:func:`gtvo.loops.closing.run_loop_closing`) and the whole-log refinement
(:func:`gtvo.refinement.run.run_refinement`)
are stages that take it and return a new one; the report is built from the last one in one place
(:func:`gtvo.report.run_report`) and written with the other outputs (:func:`gtvo.io.outputs.write_run_outputs`).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from contextlib import nullcontext
from pathlib import Path
from typing import Any, Callable, Iterable

from gtvo import __version__
from gtvo.config import OdometryConfig, as_config, config_to_yaml
from gtvo.core.atomic import ensure_output_dir, output_lock, tidy_on_failure
from gtvo.core.interrupt import raise_if_interrupted
from gtvo.core.timing import stage
from gtvo.datasets import detect_format, open_sequence
from gtvo.datasets.imu_files import imu_read_options
from gtvo.datasets.sequence import Sequence
from gtvo.errors import InputError
from gtvo.evaluation.trajectory import Trajectory
from gtvo.io.observer import RunObserver
from gtvo.io.log_settings import log_wheel_settings, wheel_settings_line
from gtvo.io.outputs import check_run_output_dir, load_plotting, write_run_outputs
from gtvo.odometry import VisualOdometry
from gtvo.odometry.estimates import frozen_warning, trust_warning
from gtvo.odometry.imu import gravity_aligned
from gtvo.odometry.result import TRACKED_OUTCOMES, OdometryResult
from gtvo.odometry.rig_report import rig_warning
from gtvo.odometry.summary import clock_timing, keyframe_covariances, odometry_result
from gtvo.odometry.wheel import wheel_coverage_warning
from gtvo.report import OdometrySummary, RunReport, run_metrics, run_report

__all__ = ["TRACKED_OUTCOMES", "keyframe_covariances", "process_sequence", "read_input", "run", "run_odometry"]


def run_odometry(seq: Sequence, config: OdometryConfig | None = None, progress: bool = False,
                 strict: bool = False, warn: Callable[[str], None] | None = None,
                 observers: Iterable[RunObserver] = (), *,
                 after_first_frame: Callable[[], None] | None = None) -> tuple[VisualOdometry, OdometryResult]:
    """Run the odometry over ``seq``: the odometry step of a run.

    A frame whose images cannot be read is skipped with a warning (and counted), unless
    ``strict``; the first frame must be readable, since everything starts from it.
    ``observers`` (:class:`gtvo.io.observer.RunObserver`, e.g. the Rerun logger) see the start,
    every processed frame and the end. ``after_first_frame`` is called once, after the first frame is
    processed (:func:`run` starts the plots' imports there: after the start-up, not in it).

    Returns:
        ``(vo, result)``: the odometry (to inspect; nothing later writes into it) and what it hands
        on (:func:`gtvo.odometry.summary.odometry_result`): the trajectory, the keyframes, the
        covariances and the summary (:func:`gtvo.odometry.summary.summarize_odometry`: frames,
        keyframes, seconds, frames per second, failures, skipped frames, ``frame_outcomes``, window
        and rig figures, timing), among others.
    """
    config = config or OdometryConfig()
    coverage = None if seq.wheel_odometry is None else wheel_coverage_warning(seq.wheel_odometry, seq.timestamps)
    vo = VisualOdometry(seq.camera, config, wheel_odometry=seq.wheel_odometry, imu=seq.imu)
    try:  # a parallel window's worker ends here, however the run ends (its figures are in the summary)
        observers = list(observers)
        for o in observers:
            o.on_start(seq, config)
        warn = warn or _warn
        skipped: list[tuple[int, str]] = []
        bar = None
        indices: Any = range(len(seq))
        if progress:
            from tqdm import tqdm  # noqa: PLC0415

            from gtvo.core.jit import announce_compilation  # noqa: PLC0415

            announce_compilation()  # the first run after an install: one line before its kernels compile
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
                if after_first_frame is not None:
                    after_first_frame()
                    after_first_frame = None
                if observers:
                    view = vo.view()
                    for o in observers:
                        o.on_frame(frame, estimate, view)
                if bar is not None:
                    bar.set_postfix(kf=len(vo.keyframes), fail=vo.failures,
                                    **({"win": len(vo.window_results)} if config.mode == "window" else {}))
        vo.finish()  # the keyframes that joined the window since its last optimisation
        seconds = time.perf_counter() - t0
        result = odometry_result(vo, seconds, skipped, seq.name)
    finally:
        vo.close()
    info = result.summary
    wheel = info.get("wheel_calibration")
    for message in (frozen_warning(vo.estimates, vo.wheel is not None), rig_warning(dict(info)),
                    trust_warning(info["frames"], info["undetermined_frames"], info["trusted_fraction"]),
                    coverage, None if wheel is None else wheel["warning"]):
        if message is not None:
            warn(message)
    if observers:
        view = vo.view()
        for o in observers:
            o.on_finish(view, result.trajectory, info)
    return vo, result


def process_sequence(seq: Sequence, config: OdometryConfig | None = None, progress: bool = False,
                     strict: bool = False, warn: Callable[[str], None] | None = None,
                     observers: Iterable[RunObserver] = ()) -> tuple[VisualOdometry, Trajectory, OdometrySummary]:
    """:func:`run_odometry` as ``(vo, trajectory, summary)``, for scripts that look into the driver."""
    vo, result = run_odometry(seq, config, progress, strict, warn, observers)
    return vo, result.trajectory, result.summary


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
        observers: see the run as it goes (:func:`run_odometry`), e.g.
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
    if not isinstance(path, Sequence):  # a log folder's wheel.yaml, read like its calibration
        config, wheel_file = log_wheel_settings(path, config)
        if wheel_file is not None:
            print(f"gtvo: {wheel_settings_line(wheel_file)}", file=sys.stdout)  # (stderr: one line for an error)
    if loop_closure:
        config = dataclasses.replace(config, loops=dataclasses.replace(config.loops, enabled=True))
    seq, fmt, out_dir = read_input(path, config, out, format, max_frames, frame_step, open_options)  # 1. read
    ahead: dict[str, str] = {}

    def after_first_frame() -> None:  # what the outputs need that is known now: made in the run, not after it
        load_plotting()
        ahead["config.yaml"] = _config_yaml(config)

    with tidy_on_failure(), output_lock(out_dir):  # a failed run leaves no empty folder; one writer at a time
        ensure_output_dir(out_dir)  # an unusable --out is reported before the long work
        _, odo = run_odometry(seq, config, progress=progress, strict=strict, observers=observers,  # 2. odometry
                              after_first_frame=after_first_frame)
        odo = _run_stages(odo, seq, progress)                    # 3. stages: loop closing, the refinement
        odo = gravity_aligned(odo)  # with an IMU: the outputs in the gravity-aligned world (docs/imu.md)
        raise_if_interrupted()
        with odo.clock.activate() if odo.clock is not None else nullcontext(), stage("outputs", absorb=True):
            metrics = run_metrics(seq, odo)                      # 4. evaluate
            points = odo.map_points()
            report = write_run_outputs(                          # 5. write, the report last
                out_dir, odo.trajectory, seq, lambda: run_report(
                    seq, odo, metrics, format=fmt, frame_step=frame_step, points=points,
                    timing=clock_timing(odo.clock, len(odo.estimates))),
                points=points, loop_closed=odo.loop_closed, covariances=odo.covariances, metrics=metrics,
                config_yaml=ahead.get("config.yaml") or _config_yaml(config))
    return {**report, "out": str(out_dir)}  # type: ignore[typeddict-item]


def _config_yaml(config: OdometryConfig) -> str:
    """``config.yaml`` of a run's outputs: the whole settings tree, for ``gtvo run --config``."""
    return config_to_yaml(config, f"gtvo {__version__}: gtvo run --config this file")


def _run_stages(odo: OdometryResult, seq: Sequence, progress: bool) -> OdometryResult:
    """Loop closing, then the whole-log refinement, each imported only when it has work (when
    ``loops.enabled``; when the window kept keyframes for the refinement): a run without them does
    not spend their imports (about 0.3 s of CPU)."""
    if odo.config.loops.enabled:
        from gtvo.loops.closing import run_loop_closing  # noqa: PLC0415 - see the docstring

        odo = run_loop_closing(odo, seq, progress)
    if odo.window_keyframes is not None:
        from gtvo.refinement.run import run_refinement  # noqa: PLC0415 - see the docstring

        odo = run_refinement(odo, seq, progress, _warn)
    return odo


def read_input(path: str | Path | Sequence, config: OdometryConfig, out: str | Path | None = None,
               format: str = "auto", max_frames: int | None = None, frame_step: int = 1,
               open_options: dict[str, Any] | None = None) -> tuple[Sequence, str | None, Path]:
    """The read step of :func:`run`: the sequence at ``path`` (or ``path`` itself; the config's
    ``wheel:`` section reads its wheel odometry), truncated to ``max_frames`` and subsampled by
    ``frame_step``; its format (as given or detected; None for a :class:`Sequence` given directly);
    and the output folder (``out``, default ``gtvo_out/<sequence name>``), checked before the long work
    (:func:`gtvo.io.outputs.check_run_output_dir`). A bag's dropped images are warned about."""
    seq = path if isinstance(path, Sequence) else open_sequence(  # type: ignore[arg-type]
        path, format=format, max_frames=max_frames, **{"wheel_options": config.wheel.read_options(),
                                                        "imu_options": imu_read_options(config.imu),
                                                        **(open_options or {})})
    out_dir = Path(out) if out is not None else Path("gtvo_out") / seq.name
    check_run_output_dir(out_dir, seq)  # before the long work
    unpaired = seq.unpaired_warning() if hasattr(seq, "unpaired_warning") else None  # a bag's dropped images
    if unpaired is not None:
        print(f"warning: {unpaired}", file=sys.stderr)
    if isinstance(path, Sequence) and max_frames is not None:
        seq = seq.truncated(max_frames)
    seq = seq.subsampled(frame_step)
    fmt = None if isinstance(path, Sequence) else (detect_format(path) if format == "auto" else format)
    return seq, fmt, out_dir


def _warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr)
