"""The whole-log refinement: one graph over every keyframe of a run, solved by the window's solvers.

:func:`refine_keyframes` takes the keyframes as the window left them (and, with loop closing, at
the loop-closed poses), builds the window's problem (:class:`gtvo.window.problem.WindowProblem`)
over all of them with the targets of :func:`gtvo.refinement.graph.covisible_targets`, adds to its
graph the accepted loop edges and (``window_edges``) the window's relative poses between
consecutive keyframes as ``BetweenFactorPose3`` (:func:`refinement_problem`),
and hands it to :func:`gtvo.window.solve_gtsam` (GTSAM's LM) or :func:`gtvo.window.solve_handrolled`.
A loop edge the refined poses reject (chi-square) is dropped and the graph solved again without
it (its factor and the photometric loop pairs it brought: the targets are chosen again); an LM that does not lower the cost leaves the keyframes as they were (docs/refinement.md).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass
from typing import Mapping, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.compact_image import packed_cache_budget
from factors.smart import JacobianBudget
from gtvo.loops.closure_graph import LoopEdge
from gtvo.config.sections.refine import RefineConfig
from gtvo.refinement.graph import covisible_targets, loop_chi2, loop_factors, window_edges
from gtvo.window.config import WindowKeyframe
from gtvo.window.gtsam_solver import solve_gtsam
from gtvo.window.handrolled import solve_handrolled
from gtvo.window.problem import RigVariable, WindowMembers, WindowProblem, WindowSensor, WindowSettings

F64 = NDArray[np.float64]


@dataclass
class RefinementResult:
    """What :func:`refine_keyframes` did.

    Attributes:
        keyframes: the keyframes after the refinement (copies; the input's when it did not run or
            was not kept), oldest first.
        ran: True when the refined keyframes are the answer.
        reason: why not (one line), None when it ran.
        solver: ``gtsam`` or ``handrolled``.
        iterations: LM iterations of the kept (or last) solve.
        cost_before, cost_after: the graph's cost at the start and at the end (None: not built).
        seconds: wall time, including the covisibility and any second solve.
        targets_mean: mean number of targets per host.
        loop_edges: loop edges in the final graph; loop_edges_dropped: those the refined poses rejected.
        covariances: frame index -> 6x6 pose covariance at the optimum (the window's
            ``covariances`` setting), None when not computed.
        rig_offset: the rig offset after the refinement (None: the rectified model).
        wheel_calibration: the wheel odometry's calibration after the refinement (None: no wheels).
    """

    keyframes: list[WindowKeyframe]
    ran: bool
    reason: str | None
    solver: str
    iterations: int = 0
    cost_before: float | None = None
    cost_after: float | None = None
    seconds: float = 0.0
    targets_mean: float = 0.0
    loop_edges: int = 0
    loop_edges_dropped: int = 0
    covariances: dict[int, F64] | None = None
    rig_offset: F64 | None = None
    wheel_calibration: F64 | None = None


def start_keyframes(keyframes: Sequence[WindowKeyframe], poses: Mapping[int, F64] | None = None
                    ) -> list[WindowKeyframe]:
    """Copies of ``keyframes`` (their images shared) to refine, at ``poses`` (frame index -> 4x4
    ``T_world_cam``, e.g. the loop-closed ones) where given."""
    out = []
    for kf in keyframes:
        c = dataclasses.replace(kf)
        if poses is not None and kf.index in poses:
            T = np.asarray(poses[kf.index], dtype=float)
            c.pose = gtsam.Pose3(gtsam.Rot3.ClosestTo(T[:3, :3]), T[:3, 3])
        out.append(c)
    return out


@dataclass(frozen=True)
class RefinementInput:
    """What the whole-log refinement takes from a run.

    Attributes:
        members: the left camera, the stereo baseline (None: RGB-D) and every keyframe of the run
            with its points and images, oldest first
            (:meth:`gtvo.window.SlidingWindowOptimizer.every_keyframe`); its targets are ignored
            (the refinement chooses them: :func:`gtvo.refinement.graph.covisible_targets`).
        window: the window's settings (weights, priors, motion prior, covariances; the LM's
            iterations and tolerance are the refinement's) and the run's photometric model; its
            ``on_iteration`` is called with ``(iteration, cost)`` after every iteration (after the bar).
        rig_offset: the run's rig offset (one variable for the log), None: the rectified model.
        sensors: the run's sensors (the window's, :class:`gtvo.window.problem.WindowSensor`; None
            entries skipped): the wheel odometry's factors between every two consecutive keyframes
            the wheel log covers and one calibration variable for the log, starting at the
            window's estimate, with the calibration's prior (a sensor is not changed; the result's
            ``wheel_calibration`` is the refined one).
        loop_edges: accepted loop edges by frame index; those between keyframes not in the list are ignored.
        start_poses: frame index -> 4x4 ``T_world_cam`` to start from (the loop-closed keyframes).
        odometry_covariances: per pair of consecutive keyframes, the tracker's covariance
            (:func:`gtvo.loops.closing.odometry_covariances`); with the refinement's ``window_edges``
            the window's relative poses join the graph with them (:func:`gtvo.refinement.graph.window_edges`).
    """

    members: WindowMembers
    window: WindowSettings = WindowSettings()
    rig_offset: F64 | None = None
    sensors: tuple[WindowSensor | None, ...] = ()
    loop_edges: Sequence[LoopEdge] = ()
    start_poses: Mapping[int, F64] | None = None
    odometry_covariances: Sequence[F64 | None] | None = None


def refinement_problem(run: RefinementInput, settings: WindowSettings, keyframes: Sequence[WindowKeyframe],
                       targets: list[list[int]], edges: Sequence[LoopEdge]) -> WindowProblem:
    """The whole-log graph as a window problem: ``keyframes`` (copies at their start) with
    ``targets``, no marginalisation prior (the gauge prior holds the oldest), the run's rig offset
    and wheels, and the loop ``edges`` (:func:`gtvo.refinement.graph.loop_factors`) added to its graph."""
    members = run.members
    rig = None if run.rig_offset is None else RigVariable(run.rig_offset)
    problem = WindowProblem.build(WindowMembers(members.camera, members.baseline, keyframes, targets), settings,
                                  None, rig, run.sensors)
    problem.factors.push_back(loop_factors(edges))
    return problem


def refine_keyframes(run: RefinementInput, config: RefineConfig | None = None,
                     progress: bool = False) -> RefinementResult:
    """Optimise one graph over every keyframe of ``run`` (module docstring; :class:`RefinementInput`)
    with the refinement's settings ``config`` (default :class:`RefineConfig`); ``progress``: a
    progress bar over the LM iterations. The input is not changed."""
    config = config or RefineConfig()
    t0 = time.perf_counter()
    keyframes = run.members.keyframes
    if len(keyframes) < 2:
        return RefinementResult(list(keyframes), False, "fewer than two keyframes", config.solver)
    camera = run.members.camera
    start = start_keyframes(keyframes, run.start_poses)
    wcfg = dataclasses.replace(run.window.config, max_iterations=config.max_iterations,
                               relative_tolerance=config.relative_tolerance)
    position = {kf.index: p for p, kf in enumerate(start)}
    edges = [e for e in run.loop_edges if e.i in position and e.j in position and e.i != e.j]

    def choose_targets(edges: Sequence[LoopEdge]) -> list[list[int]]:  # the loop pairs of these edges only
        return covisible_targets(camera, start, wcfg, config, [(position[e.i], position[e.j]) for e in edges])

    targets = choose_targets(edges)
    if not any(targets):
        return RefinementResult(list(keyframes), False, "no keyframe sees another's points", config.solver,
                                seconds=time.perf_counter() - t0)
    covs = run.odometry_covariances
    held = window_edges(keyframes, covs) if config.window_edges and covs else []
    solve = solve_gtsam if config.solver == "gtsam" else solve_handrolled
    on_iteration = run.window.on_iteration
    dropped = 0
    while True:
        current = start_keyframes(start)
        bar = _progress_bar(config.max_iterations, len(current)) if progress else None

        def step(it: int, cost: float) -> None:
            if bar is not None:
                bar.update(1)
                bar.set_postfix(cost=f"{cost:.4g}")
            if on_iteration is not None:
                on_iteration(it, cost)

        # GTSAM's LM: the host factors keep their cost passes' Jacobians within the budget
        bounded = {} if solve is solve_handrolled else {"jacobian_budget": JacobianBudget(config.jacobian_cache_mb << 20),
                                                        "stack": config.stacked_factors}
        settings = WindowSettings(wcfg, run.window.photometric, on_iteration=step, **bounded)
        try:  # the compact images' packed records: all at once when they fit the budget
            with packed_cache_budget(config.image_cache_mb << 20):
                res = solve(refinement_problem(run, settings, current, targets, edges + held))
        finally:
            if bar is not None:
                bar.close()
        chi2 = loop_chi2(edges, current)
        rejected = chi2 > config.loop_chi2
        if not np.any(rejected) or not _improved(res.initial_cost, res.cost):
            break
        edges = [e for e, r in zip(edges, rejected) if not r]  # solved again without them, from the start,
        dropped += int(np.count_nonzero(rejected))  # and without their photometric loop pairs
        targets = choose_targets(edges)
    out = RefinementResult(current, True, None, res.solver, res.iterations, res.initial_cost, res.cost,
                           time.perf_counter() - t0, float(np.mean([len(t) for t in targets])), len(edges), dropped,
                           res.covariances, res.rig_offset, res.wheel_calibration)
    if not _improved(res.initial_cost, res.cost):
        out.keyframes, out.ran, out.covariances, out.rig_offset = list(keyframes), False, None, None
        out.wheel_calibration = None
        out.reason = (f"LM diverged (cost {res.initial_cost:.6g} -> {res.cost:.6g}): the window's answer is kept"
                      if not np.isfinite(res.cost) or res.cost > res.initial_cost else
                      f"LM could not lower the cost ({res.initial_cost:.6g} after {res.iterations} iterations): "
                      "the window's answer is kept")
    return out


def _improved(before: float, after: float) -> bool:
    return bool(np.isfinite(before) and np.isfinite(after) and after < before)


def _progress_bar(total: int, keyframes: int):
    from tqdm import tqdm  # noqa: PLC0415

    return tqdm(total=total, desc=f"refinement ({keyframes} keyframes)", unit="it", dynamic_ncols=True,
                file=sys.stderr)
