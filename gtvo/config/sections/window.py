"""The ``window`` section: the settings of the sliding window of keyframes (:mod:`gtvo.window`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from gtvo.core.settings import SettingError, check_settings, setting
from gtvo.errors import show

WindowSolverName = Literal["gtsam", "handrolled"]


@dataclass(frozen=True)
class WindowConfig:
    """Settings of the window (defaults follow DSO where DSO has one; its photometric model, the
    noise of the weight ``W``, the Huber threshold and the pattern, is the
    :class:`factors.params.PhotometricConfig` the :class:`gtvo.window.SlidingWindowOptimizer` is given).

    Attributes:
        size: keyframes in the window (DSO: 7).
        lambda_stereo: weight of the host's stereo energy ``lambda E_s`` (the notes'
            ``E = E_d + lambda E_s``); 1 treats a left-right residual like a temporal one: both
            compare two images of the same sensor type with the same noise.
        affine_sigma: ``(sigma_a, sigma_b)`` of the prior of each keyframe's affine brightness
            around its tracked value. DSO without photometric calibration leaves ``(a, b)`` free;
            (1.0 log gain, 100 grey levels) is a weak prior that only keeps the system regular.
        acceleration_sigma: ``(angular rad/s^2, linear m/s^2)`` of the motion-smoothness prior, a
            :class:`factors.smoothness.ConstantVelocityFactor` on every three consecutive
            keyframes that have timestamps; None: no motion prior. The defaults are weak (a car
            brakes at up to ~8 m/s^2, a hand-held camera turns faster): with images that fix the
            poses the prior moves nothing; it keeps a window defined when they do not.
        gauge_sigma: sigma (rad, m; log gain, grey levels) of the gauge prior that fixes the oldest
            keyframe's pose and affine while no marginalisation prior exists.
        min_visible_points, min_visible_fraction: a keyframe is a target of a host when at least
            this many (and this fraction) of the host's points project into it, in front of it.
        max_iterations: LM iterations per window optimisation (DSO allows up to 6 per new keyframe;
            on KITTI 4 or 6 moved the ATE by < 1 mm for 33-82 % more time: docs/benchmarks.md,
            "Point density").
        relative_tolerance: stop when an iteration lowers the cost by less than this fraction.
        optimize_every: the window's optimisation may wait until this many keyframes have joined
            it (1: after each) while no frame was tracked against the last keyframe (keyframes at
            every frame: a car at 10 Hz) and the new keyframe's stereo depth error moves its points
            by less than the residual pattern's radius over one step; otherwise, for a keyframe not
            made from a successful track and with the fixed-lag backend it runs at once, and
            :meth:`gtvo.odometry.VisualOdometry.finish` runs it for those still waiting at the
            end. On KITTI_sequence_1 at 10 Hz 2 (the default) halves the optimisations at the same
            ATE; at 5 and 3.3 Hz, and on logs with frames between keyframes, nothing waits
            (docs/window.md, "When the window is optimised").
        marginalize: keep leaving keyframes' information as a prior (False: simply drop them).
        backend: ``"lm"``: each window optimised by a solver (:func:`solve_gtsam` or
            :func:`solve_handrolled`) and leaving keyframes marginalised by :func:`marginalize`;
            ``"fixed_lag"``: a ``gtsam.IncrementalFixedLagSmoother`` (iSAM2) holds the window,
            the keyframe's sequence number as timestamp and lag ``size - 0.5``, and marginalises
            leaving keyframes itself (docs/window.md, "Fixed-lag backend").
        covariances: after each optimisation, keep every keyframe's 6x6 pose covariance at the
            optimum (:mod:`gtvo.window.covariance`; docs/window.md, "Pose covariances"); False: none
            are computed (no cost).
        rig_calibration: stereo odometry estimates the right image's rectification error
            ``(delta_x, delta_y)`` (px) online as a window variable (docs/window.md, "Rig
            calibration"; LM backend only; RGB-D input has no rig). It is used by
            :class:`gtvo.odometry.VisualOdometry`; a :class:`gtvo.window.SlidingWindowOptimizer`
            estimates it when given a ``rig_offset``. True (the default): while neither offset is
            significant (the first pair's vertical one, then a full window's test of both every
            ``size`` windows, 3 error bars) the window solves the rectified model, exactly as
            False; once either is, both are estimated. False: the rectified model throughout.
        rig_offset_sigma: sigma (px) of the zero-mean prior on the rig offset, set once (with the
            gauge prior); afterwards the marginalisation prior carries what the window learnt.
        parallel: where the window runs in :class:`gtvo.odometry.VisualOdometry`. ``"auto"``: in this process (the sequential order) until the schedule decides, at the
            :data:`gtvo.odometry.window_schedule.AUTO_DECISION_KEYFRAME`-th keyframe, from what it
            knows of the keyframes so far (:meth:`gtvo.odometry.window_schedule.WindowSchedule.moves_to_worker`:
            how many could have left their window to the second core, keyframes at every frame
            whose stereo depths suffice), whether the rest of the run overlaps the window with the
            front end; then as ``true`` (the LM back end; the fixed-lag one stays in this process).
            The decision depends on the sequence only, never on timing.
            ``true``: the window runs in a worker process beside the front end (the second core)
            from the first keyframe, and the front end applies the window's result of its ``n``-th
            keyframe once it has sent keyframe ``n + 2`` (at once when the next frames should not
            track against its stereo depths): the same answer in every run, a little different
            from the sequential order (``false``), in which every keyframe waits for its window
            (docs/window.md, "The window beside the tracker"). ``gtvo run --parallel`` forces
            ``true``, ``--no-parallel`` ``false``; ``gtvo batch`` runs ``"auto"`` as ``false`` (one
            core per log) unless its config asks for ``true``. False (the default): measured on the
            idle 2-core machine, ``auto`` moved KITTI_sequence_1 and the raw drive to the worker
            for 0.86-1.12x the sequential frames/s, 1.15-1.2x the CPU and 1.03x the ATE
            (docs/window.md, "The window beside the tracker"), so it is asked for, not assumed.
        worker_threads: threads the parallel window's worker runs its compiled kernels on (the
            hosts' residuals of each LM pass at once, docs/window.md, "Kernel threads in the
            worker"): the results are the same, to the bit, for any number. None (the default):
            1 (on the idle 2-core machine two gave the same frames/s for more CPU, the GIL-held
            Python between the kernels being the worker's limit: docs/benchmarks.md); ``gtvo
            batch`` jobs keep one core per log (1) unless their config asks. Without
            ``parallel`` the window runs in the caller's thread alone.
    """

    size: int = setting(7, "[2, 100]")
    lambda_stereo: float = setting(1.0, "(0, 1000]")
    affine_sigma: tuple[float, float] = setting((1.0, 100.0), "(0, 1000000]")
    acceleration_sigma: tuple[float, float] | None = setting((1.0, 2.0), "(0, 1000000]")
    gauge_sigma: float = setting(1e-6, "[1e-9, 1]")
    min_visible_points: int = setting(30, "[0, 100000]")
    min_visible_fraction: float = setting(0.1, "[0, 1]")
    max_iterations: int = setting(3, "[1, 1000]")
    relative_tolerance: float = setting(1e-4, "[0, 1]")
    optimize_every: int = setting(2, "[1, 100]")
    marginalize: bool = True
    backend: Literal["lm", "fixed_lag"] = "lm"
    covariances: bool = True
    rig_calibration: bool = True
    rig_offset_sigma: float = setting(2.0, "[0.01, 100]")
    parallel: bool | Literal["auto"] = False
    worker_threads: int | None = setting(None, "[1, 16]")

    def __post_init__(self) -> None:
        check_settings(self)  # backend and the ranges declared above
        if self.parallel not in (True, False, "auto") or not isinstance(self.parallel, (bool, str)):
            raise SettingError("parallel", f"must be true, false or 'auto', got {show(self.parallel)}")
        if self.worker_threads is not None and (isinstance(self.worker_threads, bool)
                                                or not isinstance(self.worker_threads, int)):
            raise SettingError("worker_threads", f"must be a whole number, got {show(self.worker_threads)}")
        for name in ("affine_sigma", "acceleration_sigma"):
            value = getattr(self, name)
            if value is not None and len(value) != 2:
                raise SettingError(name, f"must be two numbers, got {show(value)}")


